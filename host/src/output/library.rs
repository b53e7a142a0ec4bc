//! The reference library of measured paper stocks (issue 13): one SQLite file holding
//! stocks, the sheets measured of each (one per session folder) and their spots (the
//! fitted σ°, ρs, ρd with covariance), for `gonio library` and the forensic search.
//!
//! A session folder's identity is the SHA-256 of its `MANIFEST.sha256` file's bytes: the
//! manifest names every file of the finished folder with its own SHA-256, so two folders
//! have the same identity exactly when they hold the same files, wherever they are kept.
//! A session is in the library at most once.
//!
//! Never destructive on open: a file that is not SQLite, is damaged, belongs to another
//! program or to a newer gonio is reported (path and what is wrong) and left as it is; only
//! [`OpenMode::Add`] creates a missing file. Every change is one transaction; writers wait
//! for each other (WAL journal, busy timeout), so two processes adding at once both succeed.
//!
//! The exchange format (`export`/`import`) is JSON Lines, one [`ExchangeRecord`] per spot;
//! see `docs/LIBRARY.md`.
use crate::analysis::evidence::{Sheet, Spot};
use rusqlite::{Connection, OpenFlags, OptionalExtension, TransactionBehavior, params};
use serde::{Deserialize, Serialize};
use std::io::{BufRead, Read, Write};
use std::path::{Path, PathBuf};
use std::time::Duration;
use thiserror::Error;

/// The schema this gonio writes and the newest it reads. Stored three ways: `meta`'s
/// `schema_version`, `PRAGMA user_version` (readable without knowing the tables), and
/// implied by [`APPLICATION_ID`] being ours.
pub const SCHEMA_VERSION: i64 = 1;

/// `PRAGMA application_id` of a gonio library: "goLB" in ASCII, so `file(1)` and any SQLite
/// tool can tell a gonio library from other SQLite files.
pub const APPLICATION_ID: i32 = 0x676F_4C42;

/// How long a writer waits for another process's transaction before giving up. Adds are
/// milliseconds long; 30 s covers a slow disk and many concurrent adds.
const BUSY_TIMEOUT: Duration = Duration::from_secs(30);

/// The first 16 bytes of every SQLite 3 database file.
const SQLITE_MAGIC: &[u8; 16] = b"SQLite format 3\0";

/// Why the library cannot do what was asked. Every variant names the library file or the
/// session folder concerned.
#[derive(Debug, Error)]
pub enum LibraryError {
    /// No library file (only commands that add create one).
    #[error("{path}: no library here yet: nothing has been added (gonio library add … creates it)")]
    Missing {
        /// The library file.
        path: PathBuf,
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
    #[error("{path}: an SQLite database but not a gonio library ({what}); left as it is")]
    Foreign {
        /// The file.
        path: PathBuf,
        /// Why it is not ours.
        what: String,
    },
    /// A library written by a newer gonio.
    #[error(
        "{path}: written by a newer gonio (schema {found}); this gonio reads up to {SCHEMA_VERSION}: update gonio"
    )]
    Newer {
        /// The file.
        path: PathBuf,
        /// Its schema version.
        found: i64,
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
    #[error("{path}: no stock '{name}' in the library")]
    UnknownStock {
        /// The library file.
        path: PathBuf,
        /// The name asked for.
        name: String,
    },
    /// No session, or more than one, matches the SHA-256 prefix.
    #[error("{path}: {what}")]
    SessionPrefix {
        /// The library file.
        path: PathBuf,
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
        what: String,
    },
}

/// Result of the library's operations.
pub type Result<T, E = LibraryError> = std::result::Result<T, E>;

/// Whether opening may create the file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OpenMode {
    /// Read or change an existing library; a missing one is [`LibraryError::Missing`].
    Existing,
    /// Create the library when missing (commands that add).
    Add,
}

/// A stock as given to [`Library::add_sheets`]: fields given as `None` are left as the
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
    /// When it was added to a library (UTC RFC 3339); kept through export and import.
    pub added_at: String,
    /// Its spots, in order.
    pub spots: Vec<Spot>,
}

/// One line of the exchange file: one spot, with every field of its sheet and stock so a
/// line stands on its own. Field order here is the order in the file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExchangeRecord {
    /// [`crate::schema::LIBRARY_RECORD`] (the older [`crate::schema::LIBRARY_RECORD_V1`],
    /// whose key was `format`, is imported too: the records are otherwise the same).
    #[serde(alias = "format")]
    pub schema: String,
    /// Stock name.
    pub stock: String,
    /// Stock manufacturer.
    pub manufacturer: Option<String>,
    /// Stock notes.
    pub stock_notes: Option<String>,
    /// Session identity (SHA-256 of its `MANIFEST.sha256`, lowercase hex).
    pub session_sha256: String,
    /// Sample name.
    pub sample: String,
    /// Lot or ream.
    pub lot: Option<String>,
    /// When measured.
    pub measured_at: Option<String>,
    /// Instrument serial number.
    pub instrument_serial: String,
    /// Session folder path as it was given to `add` (where the lab that measured keeps it).
    pub session_path: String,
    /// When added to the library it was exported from.
    pub added_at: String,
    /// Spot index in the sheet, from 0.
    pub spot: usize,
    /// Number of spots of the sheet (so an import can tell a sheet is whole).
    pub spots: usize,
    /// σ [deg], null when not determined.
    pub sigma_deg: Option<f64>,
    /// ρs, null when not determined.
    pub rho_s: Option<f64>,
    /// ρd, null when not determined.
    pub rho_d: Option<f64>,
    /// Covariance of (σ [deg], ρs, ρd), row by row.
    pub covariance: [[f64; 3]; 3],
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

/// The library file a command uses when `--library` is not given:
/// `$XDG_DATA_HOME/gonio/library.sqlite`, else `$HOME/.local/share/gonio/library.sqlite`
/// (the XDG base-directory rule, computed from the environment on every platform so the
/// place is the same wherever gonio runs). `None` when neither variable is set.
pub fn default_path() -> Option<PathBuf> {
    let nonempty = |name: &str| {
        std::env::var_os(name)
            .filter(|v| !v.is_empty())
            .map(PathBuf::from)
    };
    // XDG says a relative XDG_DATA_HOME is invalid and to be ignored.
    let base = nonempty("XDG_DATA_HOME")
        .filter(|p| p.is_absolute())
        .or_else(|| nonempty("HOME").map(|home| home.join(".local").join("share")))?;
    Some(base.join("gonio").join("library.sqlite"))
}

/// The identity of the session folder `dir`: SHA-256 (hex) of its `MANIFEST.sha256`.
pub fn session_identity(dir: &Path) -> Result<String> {
    let manifest = dir.join(crate::output::folder::MANIFEST);
    let bytes = std::fs::read(&manifest).map_err(|source| LibraryError::Io {
        path: manifest,
        source,
    })?;
    Ok(crate::output::manifest::sha256_hex(&bytes))
}

/// Read a finished sheet folder (`gonio measure --spots N`: its accepted spots) or session
/// folder (one spot), after checking it as `gonio verify` does (every file against the
/// manifest, the records against each other). A flagged result (`ok: false`) is refused
/// unless `allow_flagged`.
pub fn read_session_folder(
    dir: &Path,
    lot: Option<&str>,
    allow_flagged: bool,
) -> Result<SheetRecord> {
    if crate::output::folder::is_sheet_folder(dir) {
        return read_sheet_folder(dir, lot, allow_flagged);
    }
    read_spot_folder(dir, lot, allow_flagged)
}

fn read_sheet_folder(dir: &Path, lot: Option<&str>, allow_flagged: bool) -> Result<SheetRecord> {
    let bad = |what: String| LibraryError::BadSession {
        dir: dir.to_path_buf(),
        what,
    };
    let verified = crate::output::verify::verify_sheet(dir, crate::output::report::html).map_err(
        |problems| {
            let lines: Vec<String> = problems.iter().map(|p| format!("\n  {p}")).collect();
            bad(format!(
                "it does not verify (gonio verify {}):{}",
                dir.display(),
                lines.concat()
            ))
        },
    )?;
    let read = verified.sheet;
    if !read.summary.ok() && !allow_flagged {
        let flags: Vec<&str> = read.summary.flags.iter().map(|f| f.name()).collect();
        return Err(LibraryError::Flagged {
            dir: dir.to_path_buf(),
            flags: format!("{flags:?}"),
        });
    }
    let sheet = read.sheet();
    for spot in &sheet.spots {
        check_spot(spot).map_err(bad)?;
    }
    let first = read
        .spots
        .first()
        .ok_or_else(|| bad("a sheet without spots".into()))?;
    let file = first.dir.join(crate::output::folder::SESSION);
    let text = std::fs::read_to_string(&file).map_err(|source| LibraryError::Io {
        path: file.clone(),
        source,
    })?;
    let doc: crate::output::folder::SessionDoc =
        serde_json::from_str(&text).map_err(|e| bad(format!("{}: {e}", file.display())))?;
    Ok(SheetRecord {
        lot: lot.map(str::to_string),
        measured_at: doc.runs.first().map(|r| r.started.clone()),
        instrument_serial: doc.instrument.serial_number,
        session_path: dir.display().to_string(),
        session_sha256: session_identity(dir)?,
        sample: read.doc.sample.clone(),
        added_at: now_utc(),
        spots: sheet.spots,
    })
}

fn read_spot_folder(dir: &Path, lot: Option<&str>, allow_flagged: bool) -> Result<SheetRecord> {
    let bad = |what: String| LibraryError::BadSession {
        dir: dir.to_path_buf(),
        what,
    };
    if let Err(problems) = crate::output::verify::verify(dir, crate::output::report::html) {
        let lines: Vec<String> = problems.iter().map(|p| format!("\n  {p}")).collect();
        return Err(bad(format!(
            "it does not verify (gonio verify {}):{}",
            dir.display(),
            lines.concat()
        )));
    }
    let session_sha256 = session_identity(dir)?;
    let file = dir.join(crate::output::folder::SESSION);
    let text = std::fs::read_to_string(&file).map_err(|source| LibraryError::Io {
        path: file.clone(),
        source,
    })?;
    let doc: crate::output::folder::SessionDoc =
        serde_json::from_str(&text).map_err(|e| bad(format!("{}: {e}", file.display())))?;
    let ok = doc
        .rest
        .get("ok")
        .and_then(serde_json::Value::as_bool)
        .ok_or_else(|| bad(format!("{}: no boolean 'ok'", file.display())))?;
    if !ok && !allow_flagged {
        let flags = doc
            .rest
            .get("flags")
            .map_or_else(|| "no flags recorded".to_string(), |f| f.to_string());
        return Err(LibraryError::Flagged {
            dir: dir.to_path_buf(),
            flags,
        });
    }
    let result =
        crate::analysis::compare::parse_session(&file, &text).map_err(|e| bad(e.to_string()))?;
    let mut covariance = [[0.0; 3]; 3];
    for (i, row) in covariance.iter_mut().enumerate() {
        row.copy_from_slice(&result.covariance[i][..3]);
    }
    let spot = Spot {
        values: [result.values[0], result.values[1], result.values[2]],
        covariance,
    };
    check_spot(&spot).map_err(bad)?;
    Ok(SheetRecord {
        lot: lot.map(str::to_string),
        measured_at: doc.runs.first().map(|r| r.started.clone()),
        instrument_serial: doc.instrument.serial_number,
        session_path: dir.display().to_string(),
        session_sha256,
        sample: doc.sample,
        added_at: now_utc(),
        spots: vec![spot],
    })
}

/// Now, UTC RFC 3339 with milliseconds: libraries are merged across labs and time zones.
fn now_utc() -> String {
    chrono::Utc::now().to_rfc3339_opts(chrono::SecondsFormat::Millis, true)
}

/// Every number finite: SQLite stores NaN as NULL, which would change the spot.
fn check_spot(spot: &Spot) -> std::result::Result<(), String> {
    let finite = spot
        .values
        .iter()
        .flatten()
        .chain(spot.covariance.iter().flatten())
        .all(|x| x.is_finite());
    if finite {
        Ok(())
    } else {
        Err("a spot value or covariance is not a finite number".into())
    }
}

fn check_text(what: &str, value: &str) -> Result<()> {
    if value.trim().is_empty() || value.trim() != value || value.chars().any(char::is_control) {
        return Err(LibraryError::Invalid(format!(
            "{what} '{value}' must be non-empty, without leading or trailing spaces or control characters"
        )));
    }
    Ok(())
}

/// A session's SHA-256 as the library keeps it: 64 lowercase hex digits.
fn is_sha256_hex(s: &str) -> bool {
    s.len() == 64
        && s.bytes()
            .all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b))
}

const SCHEMA: &str = "
CREATE TABLE meta (
    key   TEXT PRIMARY KEY NOT NULL,
    value NOT NULL
);
CREATE TABLE stocks (
    id           INTEGER PRIMARY KEY,
    name         TEXT NOT NULL UNIQUE,
    manufacturer TEXT,
    notes        TEXT
);
CREATE TABLE sheets (
    id                INTEGER PRIMARY KEY,
    stock_id          INTEGER NOT NULL REFERENCES stocks(id) ON DELETE CASCADE,
    lot               TEXT,
    measured_at       TEXT,
    instrument_serial TEXT NOT NULL,
    session_path      TEXT NOT NULL,
    session_sha256    TEXT NOT NULL UNIQUE,
    sample            TEXT NOT NULL,
    added_at          TEXT NOT NULL
);
CREATE INDEX sheets_by_stock ON sheets(stock_id);
CREATE TABLE spots (
    sheet_id   INTEGER NOT NULL REFERENCES sheets(id) ON DELETE CASCADE,
    spot_index INTEGER NOT NULL,
    sigma_deg  REAL,
    rho_s      REAL,
    rho_d      REAL,
    -- covariance of (sigma_deg, rho_s, rho_d), row by row
    c00 REAL NOT NULL, c01 REAL NOT NULL, c02 REAL NOT NULL,
    c10 REAL NOT NULL, c11 REAL NOT NULL, c12 REAL NOT NULL,
    c20 REAL NOT NULL, c21 REAL NOT NULL, c22 REAL NOT NULL,
    PRIMARY KEY (sheet_id, spot_index)
);
";

/// What the opening probe found in a file SQLite could read.
enum Found {
    /// No tables and no ids: a new (or just created, empty) database.
    Empty,
    /// A gonio library of this schema version or older.
    Library,
}

/// An open library.
pub struct Library {
    conn: Connection,
    path: PathBuf,
}

impl std::fmt::Debug for Library {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Library").field("path", &self.path).finish()
    }
}

/// Check the file's header before SQLite opens it: SQLite would report a non-database
/// only on first use, and a truncated one not at all until the missing pages are read.
/// Returns the file's length.
fn check_header(path: &Path) -> Result<u64> {
    let io = |source| LibraryError::Io {
        path: path.to_path_buf(),
        source,
    };
    let mut file = std::fs::File::open(path).map_err(io)?;
    let len = file.metadata().map_err(io)?.len();
    if len == 0 {
        return Ok(0);
    }
    let mut header = Vec::with_capacity(100);
    Read::by_ref(&mut file)
        .take(100)
        .read_to_end(&mut header)
        .map_err(io)?;
    let not_sqlite = |what: String| LibraryError::NotSqlite {
        path: path.to_path_buf(),
        what,
    };
    if header.len() < 16 || &header[..16] != SQLITE_MAGIC {
        return Err(not_sqlite(
            "it does not begin with the SQLite header".into(),
        ));
    }
    if header.len() < 100 {
        return Err(LibraryError::Corrupt {
            path: path.to_path_buf(),
            what: format!("{len} bytes: shorter than an SQLite header (100 bytes)"),
        });
    }
    let be_u32 = |at: usize| {
        u32::from_be_bytes([header[at], header[at + 1], header[at + 2], header[at + 3]])
    };
    let page_size = match u16::from_be_bytes([header[16], header[17]]) {
        1 => 65_536u64,
        n => u64::from(n),
    };
    // The page count in the header is valid when the change counter (24) equals the
    // version-valid-for number (92). With a WAL file beside it the WAL may hold newer
    // pages, so the length is only checked without one.
    let pages = u64::from(be_u32(28));
    let wal = path.with_file_name(format!(
        "{}-wal",
        path.file_name()
            .map_or_else(Default::default, |n| n.to_string_lossy())
    ));
    if be_u32(24) == be_u32(92) && pages > 0 && !wal.exists() && len < pages * page_size {
        return Err(LibraryError::Corrupt {
            path: path.to_path_buf(),
            what: format!(
                "truncated: {len} bytes, its header says {} pages of {page_size} bytes",
                pages
            ),
        });
    }
    Ok(len)
}

/// Make a new library at `path` whole before it appears: the schema is written to a file
/// of its own beside it, which is then linked to `path` (a hard link fails if `path`
/// exists). Two processes creating one library at once never see each other's half-made
/// file (SQLite's busy handler does not cover the change to WAL of a file another process
/// is creating: "database is locked" in one run of three); the loser of the race opens the
/// winner's.
fn create_whole(path: &Path) -> Result<()> {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.subsec_nanos());
    let name = path
        .file_name()
        .map_or_else(|| "library".into(), |n| n.to_string_lossy().into_owned());
    let temporary = path.with_file_name(format!(".{name}.new-{}-{nanos}", std::process::id()));
    let sqlite = |source| LibraryError::Sqlite {
        path: temporary.clone(),
        source,
    };
    let made = (|| -> Result<()> {
        let conn = Connection::open_with_flags(
            &temporary,
            OpenFlags::SQLITE_OPEN_READ_WRITE
                | OpenFlags::SQLITE_OPEN_CREATE
                | OpenFlags::SQLITE_OPEN_NO_MUTEX,
        )
        .map_err(sqlite)?;
        let library = Library {
            conn,
            path: temporary.clone(),
        };
        library
            .conn
            .pragma_update(None, "journal_mode", "WAL")
            .map_err(sqlite)?;
        library.create_schema()?;
        // Closing checkpoints the WAL into the file and removes it.
        library.conn.close().map_err(|(_, e)| sqlite(e))?;
        match std::fs::hard_link(&temporary, path) {
            Ok(()) => Ok(()),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => Ok(()),
            Err(source) => Err(LibraryError::Io {
                path: path.to_path_buf(),
                source,
            }),
        }
    })();
    for leftover in [
        temporary.clone(),
        temporary.with_extension("new-wal"),
        PathBuf::from(format!("{}-wal", temporary.display())),
        PathBuf::from(format!("{}-shm", temporary.display())),
    ] {
        let _ = std::fs::remove_file(leftover);
    }
    made
}

impl Library {
    /// Open the library at `path`. Checks before anything is written: a non-SQLite,
    /// damaged, foreign or newer file is refused and left as it is.
    pub fn open(path: &Path, mode: OpenMode) -> Result<Library> {
        let exists = match std::fs::metadata(path) {
            Ok(m) if m.is_file() => true,
            Ok(_) => {
                return Err(LibraryError::NotSqlite {
                    path: path.to_path_buf(),
                    what: "not a regular file".into(),
                });
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => false,
            Err(source) => {
                return Err(LibraryError::Io {
                    path: path.to_path_buf(),
                    source,
                });
            }
        };
        if !exists && mode == OpenMode::Existing {
            return Err(LibraryError::Missing {
                path: path.to_path_buf(),
            });
        }
        if exists && check_header(path)? == 0 && mode == OpenMode::Existing {
            // An empty file is what an adding process leaves between creating the file and
            // its first commit (or after a crash there): no library content yet.
            return Err(LibraryError::Missing {
                path: path.to_path_buf(),
            });
        }
        if !exists && let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
            std::fs::create_dir_all(parent).map_err(|source| LibraryError::Io {
                path: parent.to_path_buf(),
                source,
            })?;
        }
        if !exists {
            create_whole(path)?;
        }
        let mut flags = OpenFlags::SQLITE_OPEN_READ_WRITE
            | OpenFlags::SQLITE_OPEN_NO_MUTEX
            | OpenFlags::SQLITE_OPEN_URI;
        if mode == OpenMode::Add {
            flags |= OpenFlags::SQLITE_OPEN_CREATE;
        }
        let sqlite = |source| LibraryError::Sqlite {
            path: path.to_path_buf(),
            source,
        };
        let conn = Connection::open_with_flags(path, flags).map_err(sqlite)?;
        conn.busy_timeout(BUSY_TIMEOUT).map_err(sqlite)?;
        let library = Library {
            conn,
            path: path.to_path_buf(),
        };
        let found = library.probe()?;
        if matches!(found, Found::Empty) && mode == OpenMode::Existing {
            return Err(LibraryError::Missing {
                path: path.to_path_buf(),
            });
        }
        // Only now, the file known to be ours or empty, anything is written to it.
        // WAL: readers never block the writer and writers queue on the busy timeout.
        library
            .conn
            .pragma_update(None, "journal_mode", "WAL")
            .map_err(sqlite)?;
        library
            .conn
            .pragma_update(None, "foreign_keys", true)
            .map_err(sqlite)?;
        if matches!(found, Found::Empty) {
            library.create_schema()?;
        }
        Ok(library)
    }

    /// The library file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    fn sqlite(&self) -> impl Fn(rusqlite::Error) -> LibraryError + '_ {
        |source| LibraryError::Sqlite {
            path: self.path.clone(),
            source,
        }
    }

    /// What the file is, read-only. SQLite's errors here mean damage: the header was
    /// SQLite's, the rest is not.
    fn probe(&self) -> Result<Found> {
        let corrupt = |e: rusqlite::Error| match e {
            rusqlite::Error::SqliteFailure(f, _)
                if f.code == rusqlite::ErrorCode::DatabaseBusy
                    || f.code == rusqlite::ErrorCode::DatabaseLocked =>
            {
                LibraryError::Sqlite {
                    path: self.path.clone(),
                    source: e,
                }
            }
            e => LibraryError::Corrupt {
                path: self.path.clone(),
                what: e.to_string(),
            },
        };
        // One read transaction: the reads below see one snapshot. Read one by one, another
        // process creating the library between them showed its tables with the header still
        // empty ("not a gonio library", one run in three of the two-process test). Dropped
        // unfinished, it rolls back: nothing is written here.
        let _snapshot =
            rusqlite::Transaction::new_unchecked(&self.conn, TransactionBehavior::Deferred)
                .map_err(corrupt)?;
        let application_id: i32 = self
            .conn
            .pragma_query_value(None, "application_id", |r| r.get(0))
            .map_err(corrupt)?;
        let user_version: i64 = self
            .conn
            .pragma_query_value(None, "user_version", |r| r.get(0))
            .map_err(corrupt)?;
        let objects: i64 = self
            .conn
            .query_row("SELECT count(*) FROM sqlite_schema", [], |r| r.get(0))
            .map_err(corrupt)?;
        let check: String = self
            .conn
            .pragma_query_value(None, "quick_check", |r| r.get(0))
            .map_err(corrupt)?;
        if check != "ok" {
            return Err(LibraryError::Corrupt {
                path: self.path.clone(),
                what: format!("SQLite's quick_check: {check}"),
            });
        }
        if application_id == 0 && user_version == 0 && objects == 0 {
            return Ok(Found::Empty);
        }
        if application_id != APPLICATION_ID {
            return Err(LibraryError::Foreign {
                path: self.path.clone(),
                what: format!(
                    "application id {application_id:#010x}, a gonio library's is {APPLICATION_ID:#010x}"
                ),
            });
        }
        if user_version > SCHEMA_VERSION {
            return Err(LibraryError::Newer {
                path: self.path.clone(),
                found: user_version,
            });
        }
        let schema_version: Option<i64> = self
            .conn
            .query_row(
                "SELECT value FROM meta WHERE key = 'schema_version'",
                [],
                |r| r.get(0),
            )
            .optional()
            .map_err(corrupt)?;
        match schema_version {
            Some(v) if v > SCHEMA_VERSION => Err(LibraryError::Newer {
                path: self.path.clone(),
                found: v,
            }),
            Some(v) if v == user_version && v >= 1 => Ok(Found::Library),
            v => Err(LibraryError::Corrupt {
                path: self.path.clone(),
                what: format!(
                    "schema_version {v:?} in meta disagrees with user_version {user_version}"
                ),
            }),
        }
    }

    /// Make the tables of a new library, once: two processes creating the same new file
    /// at once both get here, and the second finds the first's tables.
    fn create_schema(&self) -> Result<()> {
        let sqlite = self.sqlite();
        // Immediate: the check for tables and their creation are one under the write lock.
        // The connection is not shared, so an unchecked transaction (no `&mut`) is safe.
        let tx = rusqlite::Transaction::new_unchecked(&self.conn, TransactionBehavior::Immediate)
            .map_err(&sqlite)?;
        let objects: i64 = tx
            .query_row("SELECT count(*) FROM sqlite_schema", [], |r| r.get(0))
            .map_err(&sqlite)?;
        if objects == 0 {
            tx.execute_batch(SCHEMA).map_err(&sqlite)?;
            tx.execute(
                "INSERT INTO meta (key, value) VALUES ('schema_version', ?1), ('application_id', ?2), ('created_by', ?3), ('created_at', ?4)",
                params![SCHEMA_VERSION, APPLICATION_ID, format!("gonio {}", env!("CARGO_PKG_VERSION")), now_utc()],
            )
            .map_err(&sqlite)?;
            tx.pragma_update(None, "application_id", APPLICATION_ID)
                .map_err(&sqlite)?;
            tx.pragma_update(None, "user_version", SCHEMA_VERSION)
                .map_err(&sqlite)?;
        }
        tx.commit().map_err(&sqlite)?;
        Ok(())
    }

    /// A write transaction that takes the write lock at once (waiting up to the busy
    /// timeout), so that checks made in it hold until it commits.
    fn write(&mut self) -> Result<rusqlite::Transaction<'_>> {
        let path = self.path.clone();
        self.conn
            .transaction_with_behavior(TransactionBehavior::Immediate)
            .map_err(|source| LibraryError::Sqlite { path, source })
    }

    /// Add sheets under one stock, all or none: a session already in the library (by
    /// SHA-256) refuses the whole add, naming the stock it is under.
    pub fn add_sheets(&mut self, stock: &StockInfo, sheets: &[SheetRecord]) -> Result<()> {
        check_text("stock name", &stock.name)?;
        if let Some(lot) = sheets.iter().find_map(|s| s.lot.as_deref()) {
            check_text("lot", lot)?;
        }
        let path = self.path.clone();
        let sqlite = move |source| LibraryError::Sqlite {
            path: path.clone(),
            source,
        };
        let tx = self.write()?;
        let stock_id = upsert_stock(&tx, stock).map_err(|e| e.into_library(&sqlite))?;
        for sheet in sheets {
            insert_sheet(&tx, stock_id, sheet, &sheet.session_path)
                .map_err(|e| e.into_library(&sqlite))?;
        }
        tx.commit().map_err(sqlite)?;
        Ok(())
    }

    /// Every stock with its sheet and spot counts, by name.
    pub fn stocks(&self) -> Result<Vec<StockSummary>> {
        let sqlite = self.sqlite();
        let mut stmt = self
            .conn
            .prepare(
                "SELECT s.name, s.manufacturer, s.notes,
                        (SELECT count(*) FROM sheets h WHERE h.stock_id = s.id),
                        (SELECT count(*) FROM spots p JOIN sheets h ON p.sheet_id = h.id WHERE h.stock_id = s.id)
                 FROM stocks s ORDER BY s.name",
            )
            .map_err(&sqlite)?;
        let rows = stmt
            .query_map([], |r| {
                Ok(StockSummary {
                    name: r.get(0)?,
                    manufacturer: r.get(1)?,
                    notes: r.get(2)?,
                    sheets: get_count(r, 3)?,
                    spots: get_count(r, 4)?,
                })
            })
            .map_err(&sqlite)?;
        rows.collect::<rusqlite::Result<Vec<_>>>().map_err(&sqlite)
    }

    /// Remove a stock with all its sheets and spots.
    pub fn remove_stock(&mut self, name: &str) -> Result<Removed> {
        let path = self.path.clone();
        let sqlite = |source| LibraryError::Sqlite {
            path: path.clone(),
            source,
        };
        let tx = self.write()?;
        let id: Option<i64> = tx
            .query_row("SELECT id FROM stocks WHERE name = ?1", [name], |r| {
                r.get(0)
            })
            .optional()
            .map_err(sqlite)?;
        let Some(id) = id else {
            return Err(LibraryError::UnknownStock {
                path: path.clone(),
                name: name.to_string(),
            });
        };
        let sessions = column_strings(
            &tx,
            "SELECT session_sha256 FROM sheets WHERE stock_id = ?1 ORDER BY session_sha256",
            id,
        )
        .map_err(sqlite)?;
        let spots = count_spots(&tx, "h.stock_id = ?1", id).map_err(sqlite)?;
        tx.execute("DELETE FROM stocks WHERE id = ?1", [id])
            .map_err(sqlite)?;
        tx.commit().map_err(sqlite)?;
        Ok(Removed {
            stocks: vec![name.to_string()],
            sessions,
            spots,
        })
    }

    /// Remove one session, named by its SHA-256 or a prefix that only it has; its stock
    /// goes with it when it was the stock's last sheet.
    pub fn remove_session(&mut self, sha256_prefix: &str) -> Result<Removed> {
        let prefix = sha256_prefix.to_ascii_lowercase();
        let path = self.path.clone();
        if prefix.is_empty() || !prefix.bytes().all(|b| b.is_ascii_hexdigit()) {
            return Err(LibraryError::SessionPrefix {
                path,
                what: format!("'{sha256_prefix}' is not a SHA-256 or a prefix of one (hex digits)"),
            });
        }
        let sqlite = |source| LibraryError::Sqlite {
            path: path.clone(),
            source,
        };
        let tx = self.write()?;
        // Hex digits only, so the prefix holds no LIKE wildcards.
        let mut stmt = tx.prepare("SELECT id, stock_id, session_sha256 FROM sheets WHERE session_sha256 LIKE ?1 || '%' ORDER BY session_sha256").map_err(sqlite)?;
        let matches: Vec<(i64, i64, String)> = stmt
            .query_map([&prefix], |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?)))
            .map_err(sqlite)?
            .collect::<rusqlite::Result<_>>()
            .map_err(sqlite)?;
        drop(stmt);
        let (sheet_id, stock_id, sha256) = match matches.as_slice() {
            [one] => one.clone(),
            [] => {
                return Err(LibraryError::SessionPrefix {
                    path: path.clone(),
                    what: format!("no session {prefix}… in the library"),
                });
            }
            many => {
                let names: Vec<&str> = many.iter().map(|m| m.2.as_str()).collect();
                return Err(LibraryError::SessionPrefix {
                    path: path.clone(),
                    what: format!(
                        "{} sessions begin with {prefix} ({}): give more of the SHA-256",
                        many.len(),
                        names.join(", ")
                    ),
                });
            }
        };
        let spots = count_spots(&tx, "h.id = ?1", sheet_id).map_err(sqlite)?;
        tx.execute("DELETE FROM sheets WHERE id = ?1", [sheet_id])
            .map_err(sqlite)?;
        let left: i64 = tx
            .query_row(
                "SELECT count(*) FROM sheets WHERE stock_id = ?1",
                [stock_id],
                |r| r.get(0),
            )
            .map_err(sqlite)?;
        let mut stocks = Vec::new();
        if left == 0 {
            let name: String = tx
                .query_row("SELECT name FROM stocks WHERE id = ?1", [stock_id], |r| {
                    r.get(0)
                })
                .map_err(sqlite)?;
            tx.execute("DELETE FROM stocks WHERE id = ?1", [stock_id])
                .map_err(sqlite)?;
            stocks.push(name);
        }
        tx.commit().map_err(sqlite)?;
        Ok(Removed {
            stocks,
            sessions: vec![sha256],
            spots,
        })
    }

    /// Every spot as an exchange record, ordered by stock name, session SHA-256 and spot
    /// index (bytewise), so that the same contents always give the same file.
    pub fn records(&self) -> Result<Vec<ExchangeRecord>> {
        let sqlite = self.sqlite();
        let mut stmt = self
            .conn
            .prepare(
                "SELECT s.name, s.manufacturer, s.notes, h.session_sha256, h.sample, h.lot, h.measured_at, h.instrument_serial,
                        h.session_path, h.added_at, p.spot_index,
                        (SELECT count(*) FROM spots q WHERE q.sheet_id = h.id),
                        p.sigma_deg, p.rho_s, p.rho_d, p.c00, p.c01, p.c02, p.c10, p.c11, p.c12, p.c20, p.c21, p.c22
                 FROM spots p JOIN sheets h ON p.sheet_id = h.id JOIN stocks s ON h.stock_id = s.id
                 ORDER BY s.name, h.session_sha256, p.spot_index",
            )
            .map_err(&sqlite)?;
        let rows = stmt
            .query_map([], |r| {
                let mut covariance = [[0.0; 3]; 3];
                for (i, row) in covariance.iter_mut().enumerate() {
                    for (j, c) in row.iter_mut().enumerate() {
                        *c = r.get(15 + 3 * i + j)?;
                    }
                }
                Ok(ExchangeRecord {
                    schema: crate::schema::LIBRARY_RECORD.to_string(),
                    stock: r.get(0)?,
                    manufacturer: r.get(1)?,
                    stock_notes: r.get(2)?,
                    session_sha256: r.get(3)?,
                    sample: r.get(4)?,
                    lot: r.get(5)?,
                    measured_at: r.get(6)?,
                    instrument_serial: r.get(7)?,
                    session_path: r.get(8)?,
                    added_at: r.get(9)?,
                    spot: get_count(r, 10)?,
                    spots: get_count(r, 11)?,
                    sigma_deg: r.get(12)?,
                    rho_s: r.get(13)?,
                    rho_d: r.get(14)?,
                    covariance,
                })
            })
            .map_err(&sqlite)?;
        rows.collect::<rusqlite::Result<Vec<_>>>().map_err(&sqlite)
    }

    /// Write every spot to `out` as JSON Lines (see [`ExchangeRecord`]); returns the
    /// number of records. `out_path` is only for messages.
    pub fn export(&self, out: &mut dyn Write, out_path: &Path) -> Result<usize> {
        let records = self.records()?;
        let io = |source| LibraryError::Io {
            path: out_path.to_path_buf(),
            source,
        };
        for record in &records {
            let line = serde_json::to_string(record).map_err(|e| io(std::io::Error::other(e)))?;
            out.write_all(line.as_bytes()).map_err(io)?;
            out.write_all(b"\n").map_err(io)?;
        }
        out.flush().map_err(io)?;
        Ok(records.len())
    }

    /// Import a checked exchange file ([`ExchangeFile::read`]) in one transaction:
    /// sessions already in the library (by SHA-256) are skipped.
    pub fn import(&mut self, file: &ExchangeFile) -> Result<ImportCounts> {
        let (sessions, in_path) = (&file.sessions, &file.path);
        let mut counts = ImportCounts {
            records: file.records(),
            ..Default::default()
        };
        let path = self.path.clone();
        let sqlite = move |source| LibraryError::Sqlite {
            path: path.clone(),
            source,
        };
        let tx = self.write()?;
        for session in sessions {
            let present: Option<String> = tx
                .query_row(
                    "SELECT s.name FROM sheets h JOIN stocks s ON h.stock_id = s.id WHERE h.session_sha256 = ?1",
                    [&session.sheet.session_sha256],
                    |r| r.get(0),
                )
                .optional()
                .map_err(&sqlite)?;
            if present.is_some() {
                counts.sessions_skipped += 1;
                continue;
            }
            let known: bool = tx
                .query_row(
                    "SELECT count(*) > 0 FROM stocks WHERE name = ?1",
                    [&session.stock.name],
                    |r| r.get(0),
                )
                .map_err(&sqlite)?;
            counts.stocks_added += usize::from(!known);
            let stock_id =
                upsert_stock(&tx, &session.stock).map_err(|e| e.into_library(&sqlite))?;
            let what = format!("{}:{}", in_path.display(), session.first_line);
            insert_sheet(&tx, stock_id, &session.sheet, &what)
                .map_err(|e| e.into_library(&sqlite))?;
            counts.sessions_added += 1;
        }
        tx.commit().map_err(&sqlite)?;
        Ok(counts)
    }

    /// Every sheet with its stock name and session SHA-256, ordered as [`Self::records`].
    pub fn sheets(&self) -> Result<Vec<(String, String, Sheet)>> {
        let mut out: Vec<(String, String, Sheet)> = Vec::new();
        for record in self.records()? {
            let spot = Spot {
                values: [record.sigma_deg, record.rho_s, record.rho_d],
                covariance: record.covariance,
            };
            match out.last_mut() {
                Some(last) if last.1 == record.session_sha256 => last.2.spots.push(spot),
                _ => out.push((
                    record.stock,
                    record.session_sha256,
                    Sheet { spots: vec![spot] },
                )),
            }
        }
        Ok(out)
    }
}

/// An error inside a write transaction: the library's own, or SQLite's (which needs the
/// path to become one).
enum TxError {
    Library(LibraryError),
    Sqlite(rusqlite::Error),
}

impl From<rusqlite::Error> for TxError {
    fn from(e: rusqlite::Error) -> TxError {
        TxError::Sqlite(e)
    }
}

impl TxError {
    fn into_library(self, sqlite: &impl Fn(rusqlite::Error) -> LibraryError) -> LibraryError {
        match self {
            TxError::Library(e) => e,
            TxError::Sqlite(e) => sqlite(e),
        }
    }
}

/// The stock's id, made when new; manufacturer and notes given fill the library's when
/// it has none, and must agree when it has.
fn upsert_stock(tx: &rusqlite::Transaction<'_>, stock: &StockInfo) -> Result<i64, TxError> {
    let row: Option<(i64, Option<String>, Option<String>)> = tx
        .query_row(
            "SELECT id, manufacturer, notes FROM stocks WHERE name = ?1",
            [&stock.name],
            |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?)),
        )
        .optional()?;
    let Some((id, manufacturer, notes)) = row else {
        tx.execute(
            "INSERT INTO stocks (name, manufacturer, notes) VALUES (?1, ?2, ?3)",
            params![stock.name, stock.manufacturer, stock.notes],
        )?;
        return Ok(tx.last_insert_rowid());
    };
    for (field, existing, given) in [
        ("manufacturer", &manufacturer, &stock.manufacturer),
        ("notes", &notes, &stock.notes),
    ] {
        match (existing, given) {
            (Some(existing), Some(given)) if existing != given => {
                return Err(TxError::Library(LibraryError::StockConflict {
                    stock: stock.name.clone(),
                    field,
                    existing: existing.clone(),
                    given: given.clone(),
                }));
            }
            (None, Some(given)) => {
                // `field` is one of two fixed column names, never user text.
                tx.execute(
                    &format!("UPDATE stocks SET {field} = ?1 WHERE id = ?2"),
                    params![given, id],
                )?;
            }
            _ => {}
        }
    }
    Ok(id)
}

/// Insert one sheet and its spots; a session already present is [`LibraryError::Duplicate`]
/// naming its stock. `what` names the sheet's source in messages.
fn insert_sheet(
    tx: &rusqlite::Transaction<'_>,
    stock_id: i64,
    sheet: &SheetRecord,
    what: &str,
) -> Result<(), TxError> {
    let present: Option<String> = tx
        .query_row("SELECT s.name FROM sheets h JOIN stocks s ON h.stock_id = s.id WHERE h.session_sha256 = ?1", [&sheet.session_sha256], |r| r.get(0))
        .optional()?;
    if let Some(stock) = present {
        return Err(TxError::Library(LibraryError::Duplicate {
            what: what.to_string(),
            sha256: sheet.session_sha256.clone(),
            stock,
        }));
    }
    tx.execute(
        "INSERT INTO sheets (stock_id, lot, measured_at, instrument_serial, session_path, session_sha256, sample, added_at)
         VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8)",
        params![stock_id, sheet.lot, sheet.measured_at, sheet.instrument_serial, sheet.session_path, sheet.session_sha256, sheet.sample, sheet.added_at],
    )?;
    let sheet_id = tx.last_insert_rowid();
    let mut insert = tx.prepare(
        "INSERT INTO spots (sheet_id, spot_index, sigma_deg, rho_s, rho_d, c00, c01, c02, c10, c11, c12, c20, c21, c22)
         VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14)",
    )?;
    for (k, spot) in sheet.spots.iter().enumerate() {
        let c = &spot.covariance;
        insert.execute(params![
            sheet_id,
            k as i64,
            spot.values[0],
            spot.values[1],
            spot.values[2],
            c[0][0],
            c[0][1],
            c[0][2],
            c[1][0],
            c[1][1],
            c[1][2],
            c[2][0],
            c[2][1],
            c[2][2]
        ])?;
    }
    Ok(())
}

/// A count or index column as `usize` (SQLite integers are i64; a negative one in a
/// tampered file is an error, not a wrap-around).
fn get_count(row: &rusqlite::Row<'_>, index: usize) -> rusqlite::Result<usize> {
    let value: i64 = row.get(index)?;
    usize::try_from(value).map_err(|_| rusqlite::Error::IntegralValueOutOfRange(index, value))
}

fn column_strings(
    tx: &rusqlite::Transaction<'_>,
    sql: &str,
    id: i64,
) -> rusqlite::Result<Vec<String>> {
    let mut stmt = tx.prepare(sql)?;
    stmt.query_map([id], |r| r.get(0))?.collect()
}

fn count_spots(
    tx: &rusqlite::Transaction<'_>,
    condition: &str,
    id: i64,
) -> rusqlite::Result<usize> {
    tx.query_row(
        &format!(
            "SELECT count(*) FROM spots p JOIN sheets h ON p.sheet_id = h.id WHERE {condition}"
        ),
        [id],
        |r| get_count(r, 0),
    )
}

/// An exchange file read whole and checked, ready for [`Library::import`]: reading it
/// first means a bad file is refused before any library is opened or created.
#[derive(Debug)]
pub struct ExchangeFile {
    path: PathBuf,
    sessions: Vec<ImportedSession>,
}

impl ExchangeFile {
    /// Read and check the whole exchange file from `input`; `path` names it in messages.
    pub fn read(input: &mut dyn BufRead, path: &Path) -> Result<ExchangeFile> {
        Ok(ExchangeFile {
            path: path.to_path_buf(),
            sessions: parse_exchange(input, path)?,
        })
    }

    /// The spot records it holds.
    pub fn records(&self) -> usize {
        self.sessions.iter().map(|s| s.sheet.spots.len()).sum()
    }
}

/// One session of an exchange file, its records gathered.
#[derive(Debug)]
struct ImportedSession {
    stock: StockInfo,
    sheet: SheetRecord,
    first_line: usize,
    /// The `spots` field of its records.
    declared_spots: usize,
}

/// Read and check a whole exchange file: every line a record of this format, the records
/// of one session together, agreeing on the sheet and stock, with spots 0…n-1 in order.
fn parse_exchange(input: &mut dyn BufRead, in_path: &Path) -> Result<Vec<ImportedSession>> {
    let fail = |line: usize, what: String| LibraryError::Import {
        path: in_path.to_path_buf(),
        line,
        what,
    };
    let mut sessions: Vec<ImportedSession> = Vec::new();
    let mut seen = std::collections::HashSet::new();
    let mut stocks: std::collections::HashMap<String, StockInfo> = Default::default();
    let mut line_no = 0;
    let mut line = String::new();
    loop {
        line.clear();
        let n = input
            .read_line(&mut line)
            .map_err(|source| LibraryError::Io {
                path: in_path.to_path_buf(),
                source,
            })?;
        if n == 0 {
            break;
        }
        line_no += 1;
        let text = line.strip_suffix('\n').unwrap_or(&line);
        if text.trim().is_empty() {
            continue;
        }
        let record: ExchangeRecord = serde_json::from_str(text)
            .map_err(|e| fail(line_no, format!("not an exchange record: {e}")))?;
        if ![
            crate::schema::LIBRARY_RECORD,
            crate::schema::LIBRARY_RECORD_V1,
        ]
        .contains(&record.schema.as_str())
        {
            return Err(fail(
                line_no,
                format!(
                    "schema '{}', this gonio reads {} and {}",
                    record.schema,
                    crate::schema::LIBRARY_RECORD,
                    crate::schema::LIBRARY_RECORD_V1
                ),
            ));
        }
        check_text("stock name", &record.stock).map_err(|e| fail(line_no, e.to_string()))?;
        if !is_sha256_hex(&record.session_sha256) {
            return Err(fail(
                line_no,
                format!(
                    "session_sha256 '{}' is not 64 lowercase hex digits",
                    record.session_sha256
                ),
            ));
        }
        let spot = Spot {
            values: [record.sigma_deg, record.rho_s, record.rho_d],
            covariance: record.covariance,
        };
        check_spot(&spot).map_err(|e| fail(line_no, e))?;
        let stock = StockInfo {
            name: record.stock.clone(),
            manufacturer: record.manufacturer.clone(),
            notes: record.stock_notes.clone(),
        };
        match stocks.get(&stock.name) {
            Some(known) if *known != stock => {
                return Err(fail(
                    line_no,
                    format!(
                        "stock '{}' has a different manufacturer or notes than on earlier lines",
                        stock.name
                    ),
                ));
            }
            Some(_) => {}
            None => {
                stocks.insert(stock.name.clone(), stock.clone());
            }
        }
        let continues = sessions
            .last()
            .is_some_and(|s| s.sheet.session_sha256 == record.session_sha256);
        if !continues {
            if record.spot != 0 {
                return Err(fail(
                    line_no,
                    format!(
                        "session {} begins at spot {}, not 0",
                        record.session_sha256, record.spot
                    ),
                ));
            }
            if !seen.insert(record.session_sha256.clone()) {
                return Err(fail(
                    line_no,
                    format!(
                        "session {} appears again after other sessions: a session's records must be together",
                        record.session_sha256
                    ),
                ));
            }
            if let Some(last) = sessions.last() {
                check_whole(last).map_err(|what| fail(line_no - 1, what))?;
            }
            sessions.push(ImportedSession {
                stock,
                sheet: SheetRecord {
                    lot: record.lot,
                    measured_at: record.measured_at,
                    instrument_serial: record.instrument_serial,
                    session_path: record.session_path,
                    session_sha256: record.session_sha256,
                    sample: record.sample,
                    added_at: record.added_at,
                    spots: vec![spot],
                },
                first_line: line_no,
                declared_spots: record.spots,
            });
            continue;
        }
        let Some(last) = sessions.last_mut() else {
            continue;
        };
        let same_sheet = last.stock == stock
            && last.sheet.lot == record.lot
            && last.sheet.measured_at == record.measured_at
            && last.sheet.instrument_serial == record.instrument_serial
            && last.sheet.session_path == record.session_path
            && last.sheet.sample == record.sample
            && last.sheet.added_at == record.added_at;
        let same_sheet = same_sheet && last.declared_spots == record.spots;
        if !same_sheet {
            return Err(fail(
                line_no,
                format!(
                    "a record of session {} whose sheet or stock fields differ from its first record's",
                    record.session_sha256
                ),
            ));
        }
        if record.spot != last.sheet.spots.len() {
            return Err(fail(
                line_no,
                format!(
                    "spot {} of session {} out of order (expected {})",
                    record.spot,
                    record.session_sha256,
                    last.sheet.spots.len()
                ),
            ));
        }
        last.sheet.spots.push(spot);
    }
    if let Some(last) = sessions.last() {
        check_whole(last).map_err(|what| fail(line_no, what))?;
    }
    Ok(sessions)
}

/// A session's records must be all of its spots: the count each record declares.
fn check_whole(session: &ImportedSession) -> std::result::Result<(), String> {
    if session.sheet.spots.len() == session.declared_spots {
        Ok(())
    } else {
        Err(format!(
            "session {} has {} spot records, its records say {}",
            session.sheet.session_sha256,
            session.sheet.spots.len(),
            session.declared_spots
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    fn sheet(n: u64, spots: usize) -> SheetRecord {
        let spot = |k: usize| Spot {
            values: [
                Some(4.0 + n as f64 * 0.1 + k as f64),
                if k == 1 { None } else { Some(0.1 + 0.2) },
                Some(0.8 + 1e-17 * k as f64),
            ],
            covariance: [
                [1e-300, 2.5e-3, -1.0 / 3.0],
                [2.5e-3, 0.0, 7.0],
                [-1.0 / 3.0, 7.0, f64::MAX],
            ],
        };
        SheetRecord {
            lot: (n % 2 == 0).then(|| format!("ream {n}")),
            measured_at: Some(format!("2026-05-01T14:03:{:02}.000+02:00", n % 60)),
            instrument_serial: "SIM-0001".into(),
            session_path: format!("sessions/é-{n}"),
            session_sha256: crate::output::manifest::sha256_hex(&n.to_le_bytes()),
            sample: "PPC".into(),
            added_at: format!("2026-06-01T00:00:{:02}.000Z", n % 60),
            spots: (0..spots).map(spot).collect(),
        }
    }

    fn stock(name: &str) -> StockInfo {
        StockInfo {
            name: name.into(),
            manufacturer: Some("Acme «Papier»".into()),
            notes: None,
        }
    }

    fn export_bytes(library: &Library) -> Vec<u8> {
        let mut out = Vec::new();
        library.export(&mut out, Path::new("test")).expect("export");
        out
    }

    /// A library of a few stocks, sheets and spots.
    fn filled(path: &Path) -> Library {
        let mut library = Library::open(path, OpenMode::Add).expect("create");
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
        drop(Library::open(&path, OpenMode::Add).expect("create"));
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
        assert_eq!((id, user_version, schema_version), (APPLICATION_ID, 1, 1));
        // Reopening finds it, empty.
        assert!(
            Library::open(&path, OpenMode::Existing)
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
        let err = Library::open(&path, OpenMode::Existing).expect_err("missing");
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
            conn.execute("UPDATE meta SET value = 2 WHERE key = 'schema_version'", [])
                .expect("update");
            conn.pragma_update(None, "user_version", 2)
                .expect("version");
        }
        let before = folder_bytes(dir.path());
        for mode in [OpenMode::Existing, OpenMode::Add] {
            let err = Library::open(&path, mode).expect_err("newer");
            assert!(matches!(err, LibraryError::Newer { found: 2, .. }), "{err}");
            assert!(
                err.to_string().contains(
                    "written by a newer gonio (schema 2); this gonio reads up to 1: update gonio"
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
                let err = Library::open(&path, mode).expect_err("not SQLite");
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
                let err = Library::open(&path, mode).expect_err(what);
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
        let err = Library::open(&path, OpenMode::Add).expect_err("foreign");
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
            Library::open(&dir.path().join("second.sqlite"), OpenMode::Add).expect("create");
        let counts = second
            .import(
                &ExchangeFile::read(&mut exported.as_slice(), Path::new("x.jsonl")).expect("read"),
            )
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
            .import(
                &ExchangeFile::read(&mut exported.as_slice(), Path::new("x.jsonl")).expect("read"),
            )
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
        let exported = String::from_utf8(export_bytes(&filled(&dir.path().join("first.sqlite"))))
            .expect("utf-8");
        // What gonio wrote before its documents carried `schema`: the key was `format`.
        let old = exported.replace(
            &format!("\"schema\":\"{}\"", crate::schema::LIBRARY_RECORD),
            &format!("\"format\":\"{}\"", crate::schema::LIBRARY_RECORD_V1),
        );
        assert_ne!(old, exported, "the records name their schema");
        let mut second =
            Library::open(&dir.path().join("second.sqlite"), OpenMode::Add).expect("open");
        let counts = second
            .import(&ExchangeFile::read(&mut old.as_bytes(), Path::new("old.jsonl")).expect("read"))
            .expect("import");
        assert_eq!(counts.records, exported.lines().count());
        assert_eq!(
            String::from_utf8(export_bytes(&second)).expect("utf-8"),
            exported,
            "imported as the same records"
        );
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
            let err =
                ExchangeFile::read(&mut bad.as_bytes(), Path::new("x.jsonl")).expect_err("bad");
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
                    let mut library = Library::open(&path, OpenMode::Add).expect("open");
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
        let library = Library::open(&path, OpenMode::Existing).expect("open");
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
}
