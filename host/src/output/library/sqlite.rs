//! The library's SQLite file: opening it without ever harming a file that is not ours
//! (checked before SQLite writes anything), its schema, and every query and change, each
//! change one transaction with its audit entries.
use super::audit::{self, Actor, AuditEntry, NewEntry};
use super::exchange::{ExchangeFile, ExchangeRecord};
use super::store::{
    self, Contents, ImportCounts, OpenMode, Removed, StockSummary, Store, population_cache_key,
};
use super::{
    APPLICATION_ID, LibraryError, Location, Result, SCHEMA_VERSION, SheetRecord, StockInfo, now_utc,
};
use crate::analysis::evidence::{LibrarySheet, Sheet, Spot};
use crate::analysis::specimen::{Orientation, SheetLay, Side};
use rusqlite::{Connection, OpenFlags, OptionalExtension, TransactionBehavior, params};
use std::io::Read;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// How long a writer waits for another process's transaction before giving up. Adds are
/// milliseconds long; 30 s covers a slow disk and many concurrent adds.
const BUSY_TIMEOUT: Duration = Duration::from_secs(30);

/// The first 16 bytes of every SQLite 3 database file.
const SQLITE_MAGIC: &[u8; 16] = b"SQLite format 3\0";

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
" /* and AUDIT, below */;

/// The audit trail (schema 3): append-only, the triggers refusing any change or deletion
/// of an entry; AUTOINCREMENT never reuses a number, and SQLite's one writer at a time
/// numbers the entries in the order their changes committed.
const AUDIT: &str = "
CREATE TABLE audit (
    entry             INTEGER PRIMARY KEY AUTOINCREMENT,
    at                TEXT NOT NULL,
    db_user           TEXT,
    os_user           TEXT,
    host              TEXT,
    gonio_version     TEXT NOT NULL,
    action            TEXT NOT NULL CHECK (action IN (ACTIONS)),
    stock             TEXT,
    session_sha256    TEXT,
    instrument_serial TEXT,
    detail            TEXT NOT NULL
);
CREATE TRIGGER audit_is_append_only_update BEFORE UPDATE ON audit
BEGIN SELECT RAISE(ABORT, 'the audit trail is append-only'); END;
CREATE TRIGGER audit_is_append_only_delete BEFORE DELETE ON audit
BEGIN SELECT RAISE(ABORT, 'the audit trail is append-only'); END;
";

fn audit_schema() -> String {
    AUDIT.replace("ACTIONS", audit::ACTIONS)
}

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

/// An open library file.
pub(crate) struct SqliteLibrary {
    conn: Connection,
    path: PathBuf,
    location: Location,
    actor: Actor,
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
        let library = SqliteLibrary::new(conn, &temporary);
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

impl SqliteLibrary {
    fn new(conn: Connection, path: &Path) -> SqliteLibrary {
        SqliteLibrary {
            conn,
            path: path.to_path_buf(),
            location: Location::File(path.to_path_buf()),
            actor: Actor::current(),
        }
    }

    /// Open the library at `path`. Checks before anything is written: a non-SQLite,
    /// damaged, foreign or newer file is refused and left as it is.
    pub fn open(path: &Path, mode: OpenMode) -> Result<SqliteLibrary> {
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
                library: Location::File(path.to_path_buf()),
            });
        }
        if exists && check_header(path)? == 0 && mode == OpenMode::Existing {
            // An empty file is what an adding process leaves between creating the file and
            // its first commit (or after a crash there): no library content yet.
            return Err(LibraryError::Missing {
                library: Location::File(path.to_path_buf()),
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
        let library = SqliteLibrary::new(conn, path);
        let found = library.probe()?;
        if matches!(found, Found::Empty) && mode == OpenMode::Existing {
            return Err(LibraryError::Missing {
                library: Location::File(path.to_path_buf()),
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
                library: self.location.clone(),
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
                library: self.location.clone(),
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
            tx.execute_batch(&audit_schema()).map_err(&sqlite)?;
            tx.execute(
                "INSERT INTO meta (key, value) VALUES ('schema_version', ?1), ('application_id', ?2), ('created_by', ?3), ('created_at', ?4)",
                params![SCHEMA_VERSION, APPLICATION_ID, format!("gonio {}", env!("CARGO_PKG_VERSION")), now_utc()],
            )
            .map_err(&sqlite)?;
            tx.pragma_update(None, "application_id", APPLICATION_ID)
                .map_err(&sqlite)?;
            tx.pragma_update(None, "user_version", SCHEMA_VERSION)
                .map_err(&sqlite)?;
            self.append(
                &tx,
                &audit::event("create", serde_json::json!({ "schema": SCHEMA_VERSION })),
            )
            .map_err(&sqlite)?;
        }
        tx.commit().map_err(&sqlite)?;
        Ok(())
    }

    /// Append one entry to the audit trail, in the transaction `tx` of its change.
    fn append(&self, tx: &rusqlite::Transaction<'_>, entry: &NewEntry) -> rusqlite::Result<()> {
        tx.execute(
            "INSERT INTO audit (at, os_user, host, gonio_version, action, stock, session_sha256, instrument_serial, detail)
             VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9)",
            params![
                now_utc(),
                self.actor.os_user,
                self.actor.host,
                self.actor.gonio_version,
                entry.action,
                entry.stock,
                entry.session_sha256,
                entry.instrument_serial,
                entry.detail.to_string()
            ],
        )?;
        Ok(())
    }

    /// Upgrade a library of an older schema to [`SCHEMA_VERSION`], in one transaction under
    /// the write lock: the version is read again inside it, so two processes opening one old
    /// library at once upgrade it once (the second finds it done). `meta` records when and
    /// by what (`upgraded_from_N`); the audit trail begins with the upgrade's entry.
    fn upgrade(&self) -> Result<()> {
        let sqlite = self.sqlite();
        let tx = rusqlite::Transaction::new_unchecked(&self.conn, TransactionBehavior::Immediate)
            .map_err(&sqlite)?;
        let from: i64 = tx
            .pragma_query_value(None, "user_version", |r| r.get(0))
            .map_err(&sqlite)?;
        if from < SCHEMA_VERSION {
            if from == 1 {
                tx.execute_batch(UPGRADE_1_TO_2).map_err(&sqlite)?;
            }
            // 2 → 3: the audit trail, empty but for the upgrade's own entry (what was
            // added before it has no entry: the trail says where it begins).
            tx.execute_batch(&audit_schema()).map_err(&sqlite)?;
            let done = format!(
                "to schema {SCHEMA_VERSION} by gonio {} at {}",
                env!("CARGO_PKG_VERSION"),
                now_utc()
            );
            tx.execute(
                "INSERT OR REPLACE INTO meta (key, value) VALUES (?1, ?2)",
                params![format!("upgraded_from_{from}"), done],
            )
            .map_err(&sqlite)?;
            tx.execute(
                "UPDATE meta SET value = ?1 WHERE key = 'schema_version'",
                params![SCHEMA_VERSION],
            )
            .map_err(&sqlite)?;
            tx.pragma_update(None, "user_version", SCHEMA_VERSION)
                .map_err(&sqlite)?;
            let sheets: i64 = tx
                .query_row("SELECT count(*) FROM sheets", [], |r| r.get(0))
                .map_err(&sqlite)?;
            let entry = audit::event(
                "upgrade",
                serde_json::json!({ "from_schema": from, "to_schema": SCHEMA_VERSION, "sheets_before_the_trail": sheets }),
            );
            self.append(&tx, &entry).map_err(&sqlite)?;
        }
        tx.commit().map_err(&sqlite)?;
        Ok(())
    }

    /// A write transaction that takes the write lock at once (waiting up to the busy
    /// timeout), so that checks made in it hold until it commits.
    fn write(&self) -> Result<rusqlite::Transaction<'_>> {
        rusqlite::Transaction::new_unchecked(&self.conn, TransactionBehavior::Immediate)
            .map_err(self.sqlite())
    }

    /// A read transaction: the reads in it see one state of the file (WAL keeps it for
    /// them while writers go on). Dropped, it ends without writing anything.
    fn snapshot(&self) -> Result<rusqlite::Transaction<'_>> {
        rusqlite::Transaction::new_unchecked(&self.conn, TransactionBehavior::Deferred)
            .map_err(self.sqlite())
    }

    /// The sheet of row `sheet_id` as the evidence weighs it, for the entry of its removal.
    fn weighed_sheet(
        tx: &rusqlite::Transaction<'_>,
        sheet_id: i64,
    ) -> rusqlite::Result<(String, Option<String>, LibrarySheet)> {
        let (sha, stock, lot, instrument): (String, String, Option<String>, String) = tx.query_row(
            "SELECT h.session_sha256, s.name, h.lot, h.instrument_serial FROM sheets h JOIN stocks s ON h.stock_id = s.id WHERE h.id = ?1",
            [sheet_id],
            |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?)),
        )?;
        let mut stmt = tx.prepare(
            "SELECT sigma_deg, rho_s, rho_d, c00, c01, c02, c10, c11, c12, c20, c21, c22
             FROM spots WHERE sheet_id = ?1 ORDER BY spot_index",
        )?;
        let spots = stmt
            .query_map([sheet_id], |r| {
                Ok(Spot {
                    values: [r.get(0)?, r.get(1)?, r.get(2)?],
                    covariance: get_covariance(r, 3)?,
                })
            })?
            .collect::<rusqlite::Result<Vec<_>>>()?;
        Ok((
            sha,
            Some(instrument.clone()),
            LibrarySheet {
                stock,
                lot,
                instrument: Some(instrument),
                sheet: Sheet { spots },
            },
        ))
    }

    /// Delete the sheet of row `sheet_id` with its spots, and say so in the trail.
    fn delete_sheet(
        &self,
        tx: &rusqlite::Transaction<'_>,
        sheet_id: i64,
    ) -> rusqlite::Result<usize> {
        let (sha, instrument, sheet) = Self::weighed_sheet(tx, sheet_id)?;
        self.append(tx, &audit::removed(&sha, instrument.as_deref(), &sheet))?;
        tx.execute("DELETE FROM sheets WHERE id = ?1", [sheet_id])?;
        Ok(sheet.sheet.spots.len())
    }

    /// Insert the sessions of an exchange file not yet in the library (one transaction's
    /// work, `tx`), each with an `import` entry when `audited`.
    fn insert_sessions(
        &self,
        tx: &rusqlite::Transaction<'_>,
        file: &ExchangeFile,
        audited: bool,
    ) -> Result<ImportCounts> {
        let sqlite = self.sqlite();
        let mut counts = ImportCounts {
            records: file.records(),
            ..Default::default()
        };
        for session in &file.sessions {
            if has_session(tx, &session.sheet.session_sha256).map_err(&sqlite)? {
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
            let stock_id = upsert_stock(tx, &session.stock).map_err(|e| e.into_library(&sqlite))?;
            let what = format!("{}:{}", file.path.display(), session.first_line);
            insert_sheet(tx, stock_id, &session.sheet, &what)
                .map_err(|e| e.into_library(&sqlite))?;
            if audited {
                self.append(
                    tx,
                    &audit::added("import", &session.stock.name, &session.sheet),
                )
                .map_err(&sqlite)?;
            }
            counts.sessions_added += 1;
        }
        Ok(counts)
    }

    fn meta_value(&self, key: &str) -> Result<Option<serde_json::Value>> {
        let text: Option<String> = self
            .conn
            .query_row("SELECT value FROM meta WHERE key = ?1", [key], |r| r.get(0))
            .optional()
            .map_err(self.sqlite())?;
        Ok(text.and_then(|t| serde_json::from_str(&t).ok()))
    }
}

/// Whether the session of SHA-256 `sha256` is in the library (in `conn`'s transaction,
/// when it has one).
fn has_session(conn: &Connection, sha256: &str) -> rusqlite::Result<bool> {
    conn.query_row(
        "SELECT count(*) > 0 FROM sheets WHERE session_sha256 = ?1",
        [sha256],
        |r| r.get(0),
    )
}

impl Store for SqliteLibrary {
    fn location(&self) -> &Location {
        &self.location
    }

    fn add_sheets(&mut self, stock: &StockInfo, sheets: &[SheetRecord]) -> Result<()> {
        store::check_add(stock, sheets)?;
        let sqlite = self.sqlite();
        let tx = self.write()?;
        let stock_id = upsert_stock(&tx, stock).map_err(|e| e.into_library(&sqlite))?;
        for sheet in sheets {
            insert_sheet(&tx, stock_id, sheet, &sheet.session_path)
                .map_err(|e| e.into_library(&sqlite))?;
            self.append(&tx, &audit::added("add", &stock.name, sheet))
                .map_err(&sqlite)?;
        }
        tx.commit().map_err(sqlite)?;
        Ok(())
    }

    fn stock_of_session(&self, sha256: &str) -> Result<Option<String>> {
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

    fn stocks(&self) -> Result<Vec<StockSummary>> {
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

    fn remove_stock(&mut self, name: &str) -> Result<Removed> {
        let sqlite = self.sqlite();
        let tx = self.write()?;
        let id: Option<i64> = tx
            .query_row("SELECT id FROM stocks WHERE name = ?1", [name], |r| {
                r.get(0)
            })
            .optional()
            .map_err(&sqlite)?;
        let Some(id) = id else {
            return Err(LibraryError::UnknownStock {
                library: self.location.clone(),
                name: name.to_string(),
            });
        };
        let sheets: Vec<(i64, String)> = {
            let mut stmt = tx
                .prepare("SELECT id, session_sha256 FROM sheets WHERE stock_id = ?1 ORDER BY session_sha256")
                .map_err(&sqlite)?;
            stmt.query_map([id], |r| Ok((r.get(0)?, r.get(1)?)))
                .map_err(&sqlite)?
                .collect::<rusqlite::Result<_>>()
                .map_err(&sqlite)?
        };
        let mut spots = 0;
        for (sheet_id, _) in &sheets {
            spots += self.delete_sheet(&tx, *sheet_id).map_err(&sqlite)?;
        }
        tx.execute("DELETE FROM stocks WHERE id = ?1", [id])
            .map_err(&sqlite)?;
        tx.commit().map_err(&sqlite)?;
        Ok(Removed {
            stocks: vec![name.to_string()],
            sessions: sheets.into_iter().map(|(_, sha)| sha).collect(),
            spots,
        })
    }

    fn remove_session(&mut self, sha256_prefix: &str) -> Result<Removed> {
        let prefix = store::session_prefix(&self.location, sha256_prefix)?;
        let sqlite = self.sqlite();
        let tx = self.write()?;
        // Hex digits only, so the prefix holds no LIKE wildcards.
        let matches: Vec<((i64, i64), String)> = {
            let mut stmt = tx.prepare("SELECT id, stock_id, session_sha256 FROM sheets WHERE session_sha256 LIKE ?1 || '%' ORDER BY session_sha256").map_err(&sqlite)?;
            stmt.query_map([&prefix], |r| Ok(((r.get(0)?, r.get(1)?), r.get(2)?)))
                .map_err(&sqlite)?
                .collect::<rusqlite::Result<_>>()
                .map_err(&sqlite)?
        };
        let ((sheet_id, stock_id), sha256) = store::one_session(&self.location, &prefix, &matches)?;
        let spots = self.delete_sheet(&tx, sheet_id).map_err(&sqlite)?;
        let left: i64 = tx
            .query_row(
                "SELECT count(*) FROM sheets WHERE stock_id = ?1",
                [stock_id],
                |r| r.get(0),
            )
            .map_err(&sqlite)?;
        let mut stocks = Vec::new();
        if left == 0 {
            let name: String = tx
                .query_row("SELECT name FROM stocks WHERE id = ?1", [stock_id], |r| {
                    r.get(0)
                })
                .map_err(&sqlite)?;
            tx.execute("DELETE FROM stocks WHERE id = ?1", [stock_id])
                .map_err(&sqlite)?;
            stocks.push(name);
        }
        tx.commit().map_err(&sqlite)?;
        Ok(Removed {
            stocks,
            sessions: vec![sha256],
            spots,
        })
    }

    fn for_each_record(&self, each: &mut dyn FnMut(ExchangeRecord) -> Result<()>) -> Result<()> {
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

    fn has_session(&self, sha256: &str) -> Result<bool> {
        has_session(&self.conn, sha256).map_err(self.sqlite())
    }

    fn sheet_count(&self) -> Result<usize> {
        self.conn
            .query_row("SELECT count(*) FROM sheets", [], |r| get_count(r, 0))
            .map_err(self.sqlite())
    }

    fn import(&mut self, file: &ExchangeFile) -> Result<ImportCounts> {
        let tx = self.write()?;
        let counts = self.insert_sessions(&tx, file, true)?;
        tx.commit().map_err(self.sqlite())?;
        Ok(counts)
    }

    fn record_validation(&mut self, identity: &str, population: &serde_json::Value) -> Result<()> {
        let sqlite = self.sqlite();
        let tx = self.write()?;
        tx.execute(
            "INSERT OR REPLACE INTO meta (key, value) VALUES (?1, ?2)",
            params![
                format!("validated-population/{identity}"),
                store::validation_value(population).to_string()
            ],
        )
        .map_err(&sqlite)?;
        self.append(&tx, &audit::validated(identity))
            .map_err(&sqlite)?;
        tx.commit().map_err(&sqlite)?;
        Ok(())
    }

    fn validation_record(&self, identity: &str) -> Result<Option<serde_json::Value>> {
        self.meta_value(&format!("validated-population/{identity}"))
    }

    fn validation_records(&self) -> Result<Vec<(String, serde_json::Value)>> {
        let sqlite = self.sqlite();
        let mut stmt = self
            .conn
            .prepare(
                "SELECT key, value FROM meta WHERE key LIKE 'validated-population/%' ORDER BY key",
            )
            .map_err(&sqlite)?;
        let rows = stmt
            .query_map([], |r| Ok((r.get::<_, String>(0)?, r.get::<_, String>(1)?)))
            .map_err(&sqlite)?
            .collect::<rusqlite::Result<Vec<_>>>()
            .map_err(&sqlite)?;
        Ok(rows
            .into_iter()
            .filter_map(|(key, value)| {
                let identity = key.strip_prefix("validated-population/")?.to_string();
                Some((identity, serde_json::from_str(&value).ok()?))
            })
            .collect())
    }

    fn contents(&self) -> Result<Contents> {
        let sqlite = self.sqlite();
        let snapshot = self.snapshot()?;
        let mut contents = read_contents(&snapshot).map_err(&sqlite)?;
        contents.last_entry = snapshot
            .query_row("SELECT max(entry) FROM audit", [], |r| r.get(0))
            .map_err(&sqlite)?;
        Ok(contents)
    }

    fn cached_population(&self, identity: &str) -> Result<Option<serde_json::Value>> {
        self.meta_value(&population_cache_key(identity))
    }

    fn cache_population(&mut self, identity: &str, population: &serde_json::Value) -> Result<()> {
        let sqlite = self.sqlite();
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

    fn history(&self, each: &mut dyn FnMut(AuditEntry) -> Result<()>) -> Result<()> {
        let sqlite = self.sqlite();
        let mut stmt = self
            .conn
            .prepare(
                "SELECT entry, at, db_user, os_user, host, gonio_version, action, stock, session_sha256, instrument_serial, detail
                 FROM audit ORDER BY entry",
            )
            .map_err(&sqlite)?;
        let mut rows = stmt.query([]).map_err(&sqlite)?;
        while let Some(r) = rows.next().map_err(&sqlite)? {
            let entry = (|| -> rusqlite::Result<AuditEntry> {
                let detail: String = r.get(10)?;
                Ok(AuditEntry {
                    entry: r.get(0)?,
                    at: r.get(1)?,
                    db_user: r.get(2)?,
                    os_user: r.get(3)?,
                    host: r.get(4)?,
                    gonio_version: r.get(5)?,
                    action: r.get(6)?,
                    stock: r.get(7)?,
                    session_sha256: r.get(8)?,
                    instrument_serial: r.get(9)?,
                    detail: serde_json::from_str(&detail)
                        .unwrap_or(serde_json::Value::String(detail)),
                })
            })()
            .map_err(&sqlite)?;
            each(entry)?;
        }
        Ok(())
    }

    fn receive(
        &mut self,
        file: &ExchangeFile,
        history: &[AuditEntry],
        validations: &[(String, serde_json::Value)],
        from: &Location,
    ) -> Result<()> {
        let sqlite = self.sqlite();
        let tx = self.write()?;
        let source = from.to_string();
        for entry in history {
            self.append(&tx, &audit::migrated(entry, &source))
                .map_err(&sqlite)?;
        }
        let counts = self.insert_sessions(&tx, file, false)?;
        for (identity, value) in validations {
            tx.execute(
                "INSERT OR REPLACE INTO meta (key, value) VALUES (?1, ?2)",
                params![
                    format!("validated-population/{identity}"),
                    value.to_string()
                ],
            )
            .map_err(&sqlite)?;
        }
        let entry = audit::event(
            "migrate",
            serde_json::json!({ "from": source, "sessions": counts.sessions_added, "records": counts.records, "audit_entries": history.len(), "validations": validations.len() }),
        );
        self.append(&tx, &entry).map_err(&sqlite)?;
        tx.commit().map_err(&sqlite)?;
        Ok(())
    }
}

/// Every sheet with its lay, ordered as the export (see [`Contents`]). Only what the
/// evidence is made of is read (not each spot's whole record: a search of a library of
/// 10⁵ sheets held 380 MiB of records), each table once in its own order and the sheets
/// put in order here: SQLite's sort of every spot wrote and read temporary files for most
/// of a large library's search.
fn read_contents(tx: &rusqlite::Transaction<'_>) -> rusqlite::Result<Contents> {
    let mut stmt = tx.prepare(
        "SELECT h.id, s.name, h.session_sha256, h.lot, h.instrument_serial, h.orientation, h.side
         FROM sheets h JOIN stocks s ON h.stock_id = s.id",
    )?;
    let mut rows = stmt.query([])?;
    let mut index = std::collections::HashMap::new();
    let mut sheets: Vec<SheetRows> = Vec::new();
    while let Some(r) = rows.next()? {
        let id: i64 = r.get(0)?;
        index.insert(id, sheets.len());
        sheets.push(SheetRows {
            sha256: r.get(2)?,
            sheet: LibrarySheet {
                stock: r.get(1)?,
                lot: r.get(3)?,
                instrument: Some(r.get(4)?),
                sheet: Sheet::default(),
            },
            lay: SheetLay {
                orientation: get_orientation(r, 5)?,
                side: get_side(r, 6)?,
            },
            spots: Vec::new(),
        });
    }
    drop(rows);
    let mut stmt = tx.prepare(
        "SELECT sheet_id, spot_index, sigma_deg, rho_s, rho_d,
                c00, c01, c02, c10, c11, c12, c20, c21, c22
         FROM spots",
    )?;
    let mut rows = stmt.query([])?;
    while let Some(r) = rows.next()? {
        let sheet_id: i64 = r.get(0)?;
        // A spot of no sheet (possible only where foreign keys were not enforced) is
        // not part of any sheet, as the join of an export leaves it out.
        let Some(&k) = index.get(&sheet_id) else {
            continue;
        };
        let spot = Spot {
            values: [r.get(2)?, r.get(3)?, r.get(4)?],
            covariance: get_covariance(r, 5)?,
        };
        sheets[k].spots.push((r.get(1)?, spot));
    }
    Ok(Contents {
        sheets: in_export_order(sheets),
        last_entry: None,
    })
}

/// A sheet as read, its spots with their indices (put in order by [`in_export_order`]).
pub(crate) struct SheetRows {
    pub sha256: String,
    pub sheet: LibrarySheet,
    pub lay: SheetLay,
    pub spots: Vec<(i64, Spot)>,
}

/// Sheets with spots, each's spots by index, ordered by stock name and SHA-256 bytewise
/// (as SQLite's ORDER BY of the export, and PostgreSQL's under COLLATE "C").
pub(crate) fn in_export_order(sheets: Vec<SheetRows>) -> Vec<(String, LibrarySheet, SheetLay)> {
    let mut out: Vec<(String, LibrarySheet, SheetLay)> = sheets
        .into_iter()
        .filter(|s| !s.spots.is_empty())
        .map(|mut s| {
            s.spots.sort_by_key(|(k, _)| *k);
            s.sheet.sheet.spots = s.spots.into_iter().map(|(_, spot)| spot).collect();
            (s.sha256, s.sheet, s.lay)
        })
        .collect();
    out.sort_by(|a, b| a.1.stock.cmp(&b.1.stock).then_with(|| a.0.cmp(&b.0)));
    out
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
    for (field, given) in
        store::stock_fields_to_fill(stock, &manufacturer, &notes).map_err(TxError::Library)?
    {
        // `field` is one of two fixed column names, never user text.
        tx.execute(
            &format!("UPDATE stocks SET {field} = ?1 WHERE id = ?2"),
            params![given, id],
        )?;
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
