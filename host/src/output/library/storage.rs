//! The library's SQLite file: opening it without ever harming a file that is not ours
//! (checked before SQLite writes anything), its schema, and every query and change, each
//! change one transaction.
use super::exchange::{ExchangeFile, ExchangeRecord};
use super::{
    APPLICATION_ID, LibraryError, Result, SCHEMA_VERSION, SheetRecord, StockInfo, check_text,
    now_utc,
};
use crate::analysis::evidence::{LibrarySheet, Sheet, Spot};
use crate::analysis::specimen::{Orientation, SheetLay, Side};
use rusqlite::{Connection, OpenFlags, OptionalExtension, TransactionBehavior, params};
use serde::Serialize;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::time::Duration;

/// How long a writer waits for another process's transaction before giving up. Adds are
/// milliseconds long; 30 s covers a slow disk and many concurrent adds.
const BUSY_TIMEOUT: Duration = Duration::from_secs(30);

/// The first 16 bytes of every SQLite 3 database file.
const SQLITE_MAGIC: &[u8; 16] = b"SQLite format 3\0";

/// Whether opening may create the file.
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

/// The library file a command uses when `--library` is not given:
/// `$XDG_DATA_HOME/gonio/library.sqlite`, else `$HOME/.local/share/gonio/library.sqlite`
/// (the XDG base-directory rule, computed from the environment on every platform so the
/// place is the same wherever gonio runs). `None` when neither variable is set.
pub fn default_path() -> Option<PathBuf> {
    Some(crate::instrument::data_dir()?.join("library.sqlite"))
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
    added_at          TEXT NOT NULL,
    orientation       TEXT CHECK (orientation IN ('md', 'cd')),
    side              TEXT CHECK (side IN ('felt', 'wire'))
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
    /// A gonio library of this schema version or older (its version).
    Library(i64),
}

/// What upgrades a library of schema version 1 to 2: its sheets gain their orientation and
/// side, unknown (NULL) for every sheet already in it (a version 1 library never recorded
/// them). Columns added, nothing rewritten: every record is kept as it is.
const UPGRADE_1_TO_2: &str = "
ALTER TABLE sheets ADD COLUMN orientation TEXT CHECK (orientation IN ('md', 'cd'));
ALTER TABLE sheets ADD COLUMN side TEXT CHECK (side IN ('felt', 'wire'));
";

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
        match found {
            Found::Empty => library.create_schema()?,
            Found::Library(version) if version < SCHEMA_VERSION => library.upgrade()?,
            Found::Library(_) => {}
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
            Some(v) if v == user_version && v >= 1 => Ok(Found::Library(v)),
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

    /// Upgrade a library of an older schema to [`SCHEMA_VERSION`], in one transaction under
    /// the write lock: the version is read again inside it, so two processes opening one old
    /// library at once upgrade it once (the second finds it done). `meta` records when and
    /// by what (`upgraded_from_1`).
    fn upgrade(&self) -> Result<()> {
        let sqlite = self.sqlite();
        let tx = rusqlite::Transaction::new_unchecked(&self.conn, TransactionBehavior::Immediate)
            .map_err(&sqlite)?;
        let version: i64 = tx
            .pragma_query_value(None, "user_version", |r| r.get(0))
            .map_err(&sqlite)?;
        if version == 1 {
            tx.execute_batch(UPGRADE_1_TO_2).map_err(&sqlite)?;
            tx.execute(
                "INSERT OR REPLACE INTO meta (key, value) VALUES ('upgraded_from_1', ?1)",
                params![format!(
                    "to schema 2 by gonio {} at {}",
                    env!("CARGO_PKG_VERSION"),
                    now_utc()
                )],
            )
            .map_err(&sqlite)?;
            tx.execute(
                "UPDATE meta SET value = ?1 WHERE key = 'schema_version'",
                params![SCHEMA_VERSION],
            )
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
        // The same check as `import` and `read_session_folder` make: a caller of this API
        // cannot store a spot the commands would refuse.
        for sheet in sheets {
            for (k, spot) in sheet.spots.iter().enumerate() {
                super::check_spot(spot).map_err(|e| {
                    LibraryError::Invalid(format!("{}: spot {k}: {e}", sheet.session_path))
                })?;
            }
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

    /// The stock a session (by its SHA-256) is under, if it is in the library.
    pub fn stock_of_session(&self, sha256: &str) -> Result<Option<String>> {
        let sqlite = self.sqlite();
        self.conn
            .query_row(
                "SELECT s.name FROM sheets h JOIN stocks s ON h.stock_id = s.id WHERE h.session_sha256 = ?1",
                [sha256],
                |r| r.get(0),
            )
            .optional()
            .map_err(sqlite)
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
        let mut out = Vec::new();
        self.for_each_record(|record| {
            out.push(record);
            Ok(())
        })?;
        Ok(out)
    }

    /// Every spot as an exchange record, in the order of [`Self::records`], given to `each`
    /// one at a time as it is read: a library of 10⁵ sheets is hundreds of megabytes of
    /// records that need never be held at once. `each`'s error stops the reading.
    pub fn for_each_record(
        &self,
        mut each: impl FnMut(ExchangeRecord) -> Result<()>,
    ) -> Result<()> {
        let sqlite = self.sqlite();
        let mut stmt = self
            .conn
            .prepare(
                "SELECT s.name, s.manufacturer, s.notes, h.session_sha256, h.sample, h.lot, h.measured_at, h.instrument_serial,
                        h.session_path, h.added_at, p.spot_index,
                        (SELECT count(*) FROM spots q WHERE q.sheet_id = h.id),
                        p.sigma_deg, p.rho_s, p.rho_d, p.c00, p.c01, p.c02, p.c10, p.c11, p.c12, p.c20, p.c21, p.c22,
                        h.orientation, h.side
                 FROM spots p JOIN sheets h ON p.sheet_id = h.id JOIN stocks s ON h.stock_id = s.id
                 ORDER BY s.name, h.session_sha256, p.spot_index",
            )
            .map_err(&sqlite)?;
        let mut rows = stmt.query([]).map_err(&sqlite)?;
        while let Some(r) = rows.next().map_err(&sqlite)? {
            let record = (|| -> rusqlite::Result<ExchangeRecord> {
                Ok(ExchangeRecord {
                    schema: crate::schema::LIBRARY_RECORD.to_string(),
                    stock: r.get(0)?,
                    manufacturer: r.get(1)?,
                    stock_notes: r.get(2)?,
                    session_sha256: r.get(3)?,
                    sample: r.get(4)?,
                    lot: r.get(5)?,
                    measured_at: r.get(6)?,
                    orientation: get_orientation(r, 24)?,
                    side: get_side(r, 25)?,
                    instrument_serial: r.get(7)?,
                    session_path: r.get(8)?,
                    added_at: r.get(9)?,
                    spot: get_count(r, 10)?,
                    spots: get_count(r, 11)?,
                    sigma_deg: r.get(12)?,
                    rho_s: r.get(13)?,
                    rho_d: r.get(14)?,
                    covariance: get_covariance(r, 15)?,
                })
            })()
            .map_err(&sqlite)?;
            each(record)?;
        }
        Ok(())
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
        self.for_each_record(|record| {
            serde_json::to_writer(&mut out, &record).map_err(|e| io(std::io::Error::other(e)))?;
            out.write_all(b"\n").map_err(io)?;
            records += 1;
            Ok(())
        })?;
        out.flush().map_err(io)?;
        Ok(records)
    }

    /// Whether the session of SHA-256 `sha256` is in the library.
    pub fn has_session(&self, sha256: &str) -> Result<bool> {
        self.conn
            .query_row(
                "SELECT count(*) > 0 FROM sheets WHERE session_sha256 = ?1",
                [sha256],
                |r| r.get(0),
            )
            .map_err(self.sqlite())
    }

    /// How many sheets (sessions) the library holds.
    pub fn sheet_count(&self) -> Result<usize> {
        self.conn
            .query_row("SELECT count(*) FROM sheets", [], |r| get_count(r, 0))
            .map_err(self.sqlite())
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

    /// Record the population `gonio forensic --library` validated from the library's
    /// contents of identity `identity` (`evidence::population::contents_identity`), with its
    /// validation: kept in `meta` under `validated-population/<identity>`, so contents
    /// changed since are simply not found.
    pub fn record_validation(
        &mut self,
        identity: &str,
        population: &serde_json::Value,
    ) -> Result<()> {
        let path = self.path.clone();
        let sqlite = |source| LibraryError::Sqlite {
            path: path.clone(),
            source,
        };
        let record = serde_json::json!({
            "validated_at": now_utc(),
            "validated_by": format!("gonio {}", env!("CARGO_PKG_VERSION")),
            "population": population,
        });
        let tx = self.write()?;
        tx.execute(
            "INSERT OR REPLACE INTO meta (key, value) VALUES (?1, ?2)",
            params![
                format!("validated-population/{identity}"),
                record.to_string()
            ],
        )
        .map_err(&sqlite)?;
        tx.commit().map_err(&sqlite)?;
        Ok(())
    }

    /// The population validated from the contents of identity `identity`, with when and by
    /// what, if one was recorded.
    pub fn validation_record(&self, identity: &str) -> Result<Option<serde_json::Value>> {
        let sqlite = self.sqlite();
        let text: Option<String> = self
            .conn
            .query_row(
                "SELECT value FROM meta WHERE key = ?1",
                params![format!("validated-population/{identity}")],
                |r| r.get(0),
            )
            .optional()
            .map_err(&sqlite)?;
        Ok(text.and_then(|t| serde_json::from_str(&t).ok()))
    }

    /// How every sheet lay, as (session SHA-256, stock, lay), in no particular order: kept
    /// apart from [`Self::sheets`], whose sheets make the population and its identity
    /// (the population does not weigh the lay, so recorded validations stay found).
    pub fn lays(&self) -> Result<Vec<(String, String, SheetLay)>> {
        let sqlite = self.sqlite();
        let mut stmt = self
            .conn
            .prepare(
                "SELECT h.session_sha256, s.name, h.orientation, h.side
                 FROM sheets h JOIN stocks s ON h.stock_id = s.id",
            )
            .map_err(&sqlite)?;
        let rows = stmt
            .query_map([], |r| {
                Ok((
                    r.get(0)?,
                    r.get(1)?,
                    SheetLay {
                        orientation: get_orientation(r, 2)?,
                        side: get_side(r, 3)?,
                    },
                ))
            })
            .map_err(&sqlite)?;
        rows.collect::<rusqlite::Result<Vec<_>>>().map_err(&sqlite)
    }

    /// Every sheet (its stock, lot, instrument and spots) with its session SHA-256, ordered
    /// as [`Self::records`]. Only what the evidence is made of is read (not each spot's
    /// whole record: a search of a library of 10⁵ sheets held 380 MiB of records), each
    /// table once in its own order and the sheets put in order here: SQLite's sort of
    /// every spot wrote and read temporary files for most of a large library's search.
    pub fn sheets(&self) -> Result<Vec<(String, LibrarySheet)>> {
        let sqlite = self.sqlite();
        let mut stmt = self
            .conn
            .prepare(
                "SELECT h.id, s.name, h.session_sha256, h.lot, h.instrument_serial
                 FROM sheets h JOIN stocks s ON h.stock_id = s.id",
            )
            .map_err(&sqlite)?;
        let mut rows = stmt.query([]).map_err(&sqlite)?;
        let mut index = std::collections::HashMap::new();
        // A sheet's stock, the sheet, and its spots with their row ids (sorted below).
        type SheetRows = (String, LibrarySheet, Vec<(i64, Spot)>);
        let mut sheets: Vec<SheetRows> = Vec::new();
        while let Some(r) = rows.next().map_err(&sqlite)? {
            let id: i64 = r.get(0).map_err(&sqlite)?;
            index.insert(id, sheets.len());
            sheets.push((
                r.get(2).map_err(&sqlite)?,
                LibrarySheet {
                    stock: r.get(1).map_err(&sqlite)?,
                    lot: r.get(3).map_err(&sqlite)?,
                    instrument: Some(r.get(4).map_err(&sqlite)?),
                    sheet: Sheet::default(),
                },
                Vec::new(),
            ));
        }
        drop(rows);
        let mut stmt = self
            .conn
            .prepare(
                "SELECT sheet_id, spot_index, sigma_deg, rho_s, rho_d,
                        c00, c01, c02, c10, c11, c12, c20, c21, c22
                 FROM spots",
            )
            .map_err(&sqlite)?;
        let mut rows = stmt.query([]).map_err(&sqlite)?;
        while let Some(r) = rows.next().map_err(&sqlite)? {
            let sheet_id: i64 = r.get(0).map_err(&sqlite)?;
            // A spot of no sheet (possible only where foreign keys were not enforced) is
            // not part of any sheet, as the join of an export leaves it out.
            let Some(&k) = index.get(&sheet_id) else {
                continue;
            };
            let spot = Spot {
                values: [
                    r.get(2).map_err(&sqlite)?,
                    r.get(3).map_err(&sqlite)?,
                    r.get(4).map_err(&sqlite)?,
                ],
                covariance: get_covariance(r, 5).map_err(&sqlite)?,
            };
            sheets[k].2.push((r.get(1).map_err(&sqlite)?, spot));
        }
        let mut out: Vec<(String, LibrarySheet)> = sheets
            .into_iter()
            .filter(|(_, _, spots)| !spots.is_empty())
            .map(|(sha256, mut sheet, mut spots)| {
                spots.sort_by_key(|(k, _)| *k);
                sheet.sheet.spots = spots.into_iter().map(|(_, spot)| spot).collect();
                (sha256, sheet)
            })
            .collect();
        // Bytewise, as SQLite's ORDER BY of the export.
        out.sort_by(|a, b| a.1.stock.cmp(&b.1.stock).then_with(|| a.0.cmp(&b.0)));
        Ok(out)
    }

    /// The population last made from the library's contents of identity `identity`
    /// (`evidence::population::contents_identity`) by this version of gonio, if it is
    /// still cached: making one takes time that grows with the square of the stocks.
    pub fn cached_population(&self, identity: &str) -> Result<Option<serde_json::Value>> {
        let text: Option<String> = self
            .conn
            .query_row(
                "SELECT value FROM meta WHERE key = ?1",
                params![population_cache_key(identity)],
                |r| r.get(0),
            )
            .optional()
            .map_err(self.sqlite())?;
        Ok(text.and_then(|t| serde_json::from_str(&t).ok()))
    }

    /// Cache `population`, made from the contents of identity `identity`, in place of any
    /// cached before: contents changed since have another identity, so a cached
    /// population is never used for contents it was not made from, and only the last is
    /// kept.
    pub fn cache_population(
        &mut self,
        identity: &str,
        population: &serde_json::Value,
    ) -> Result<()> {
        let path = self.path.clone();
        let sqlite = |source| LibraryError::Sqlite {
            path: path.clone(),
            source,
        };
        let tx = self.write()?;
        tx.execute("DELETE FROM meta WHERE key LIKE 'population-cache/%'", [])
            .map_err(&sqlite)?;
        tx.execute(
            "INSERT INTO meta (key, value) VALUES (?1, ?2)",
            params![population_cache_key(identity), population.to_string()],
        )
        .map_err(&sqlite)?;
        tx.commit().map_err(&sqlite)?;
        Ok(())
    }
}

/// Where [`Library::cached_population`] keeps a population: under the gonio that made it
/// (another version may make it differently) and the contents it was made from.
fn population_cache_key(identity: &str) -> String {
    format!(
        "population-cache/gonio {}/{identity}",
        env!("CARGO_PKG_VERSION")
    )
}

/// The orientation in column `index`: NULL is unknown; anything but `md` or `cd` (only in a
/// file changed by other means: the column's CHECK refuses it) is an error, not unknown.
fn get_orientation(row: &rusqlite::Row<'_>, index: usize) -> rusqlite::Result<Option<Orientation>> {
    let text: Option<String> = row.get(index)?;
    text.map(|t| match t.as_str() {
        "md" => Ok(Orientation::Md),
        "cd" => Ok(Orientation::Cd),
        _ => Err(not_a_lay(index, "an orientation (md, cd)", t)),
    })
    .transpose()
}

/// The side in column `index`, as [`get_orientation`].
fn get_side(row: &rusqlite::Row<'_>, index: usize) -> rusqlite::Result<Option<Side>> {
    let text: Option<String> = row.get(index)?;
    text.map(|t| match t.as_str() {
        "felt" => Ok(Side::Felt),
        "wire" => Ok(Side::Wire),
        _ => Err(not_a_lay(index, "a side (felt, wire)", t)),
    })
    .transpose()
}

fn not_a_lay(index: usize, what: &str, text: String) -> rusqlite::Error {
    rusqlite::Error::FromSqlConversionFailure(
        index,
        rusqlite::types::Type::Text,
        format!("'{text}' is not {what}").into(),
    )
}

/// The 3×3 covariance in the nine columns from `first`, row by row.
fn get_covariance(row: &rusqlite::Row<'_>, first: usize) -> rusqlite::Result<[[f64; 3]; 3]> {
    let mut covariance = [[0.0; 3]; 3];
    for (i, line) in covariance.iter_mut().enumerate() {
        for (j, c) in line.iter_mut().enumerate() {
            *c = row.get(first + 3 * i + j)?;
        }
    }
    Ok(covariance)
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
        "INSERT INTO sheets (stock_id, lot, measured_at, instrument_serial, session_path, session_sha256, sample, added_at, orientation, side)
         VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10)",
        params![stock_id, sheet.lot, sheet.measured_at, sheet.instrument_serial, sheet.session_path, sheet.session_sha256, sheet.sample, sheet.added_at, sheet.lay.orientation.map(Orientation::name), sheet.lay.side.map(Side::name)],
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
