//! The library in a PostgreSQL database an institute shares (issue 29): the same tables as
//! the SQLite file in a schema `gonio` of their own, the same schema version rules, the same
//! exchange records; roles the database enforces, and an audit trail it stamps and keeps.
//!
//! - **Roles.** [`EXAMINER_ROLE`] may read everything and cache populations (search,
//!   compare, list, export, history); [`CURATOR_ROLE`] is an examiner who may also add,
//!   remove and validate stocks. They are granted on the tables, so the database itself
//!   refuses an examiner's add whatever client makes it; gonio says which role is needed.
//!   An administrator grants them to logins (`GRANT gonio_curator TO alice`).
//! - **The trail.** Each entry's time and role are stamped by a trigger (`now()`,
//!   `session_user`), not given by the client; a trigger refuses every UPDATE, DELETE and
//!   TRUNCATE of it, and no role is granted either.
//! - **Many at once.** Every change takes one lock (SHARE ROW EXCLUSIVE on `gonio.stocks`,
//!   which only curators may take) for its transaction: changes are one at a time, their
//!   entries numbered in commit order, and the uniqueness checks made in them hold until
//!   they commit (the unique keys on stock names and session identities are there too).
//!   Reads that must agree ([`Store::contents`]) are one REPEATABLE READ snapshot, so a
//!   search weighs a state that existed, never half an add.
use super::audit::{self, Actor, AuditEntry, NewEntry};
use super::exchange::{ExchangeFile, ExchangeRecord};
use super::sqlite::{SheetRows, in_export_order};
use super::store::{
    self, Contents, ImportCounts, OpenMode, Removed, StockSummary, Store, population_cache_key,
};
use super::{
    APPLICATION_ID, LibraryError, Location, Result, SCHEMA_VERSION, SheetRecord, StockInfo,
};
use crate::analysis::evidence::{LibrarySheet, Sheet, Spot};
use crate::analysis::specimen::{Orientation, SheetLay, Side};
use postgres::error::SqlState;
use postgres::fallible_iterator::FallibleIterator;
use postgres::{Client, IsolationLevel, NoTls, Row, Transaction};
use std::cell::RefCell;
use std::str::FromStr;
use std::time::Duration;

/// The role that may search and compare (read, and cache populations).
pub const EXAMINER_ROLE: &str = "gonio_examiner";
/// The role that may also add, remove and validate stocks.
pub const CURATOR_ROLE: &str = "gonio_curator";

/// How long a connection attempt may take before gonio says the server did not answer.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(10);

/// The tables (schema version 3, as SQLite's), the trail's triggers and the roles' rights.
/// `ACTIONS` is replaced by the trail's actions.
const SCHEMA: &str = r#"
CREATE SCHEMA gonio;
CREATE TABLE gonio.meta (
    key   text PRIMARY KEY,
    value text NOT NULL
);
CREATE TABLE gonio.stocks (
    id           bigint GENERATED ALWAYS AS IDENTITY PRIMARY KEY,
    name         text NOT NULL UNIQUE,
    manufacturer text,
    notes        text
);
CREATE TABLE gonio.sheets (
    id                bigint GENERATED ALWAYS AS IDENTITY PRIMARY KEY,
    stock_id          bigint NOT NULL REFERENCES gonio.stocks(id) ON DELETE CASCADE,
    lot               text,
    measured_at       text,
    instrument_serial text NOT NULL,
    session_path      text NOT NULL,
    session_sha256    text NOT NULL UNIQUE,
    sample            text NOT NULL,
    added_at          text NOT NULL,
    orientation       text CHECK (orientation IN ('md', 'cd')),
    side              text CHECK (side IN ('felt', 'wire'))
);
CREATE INDEX sheets_by_stock ON gonio.sheets(stock_id);
CREATE TABLE gonio.spots (
    sheet_id   bigint NOT NULL REFERENCES gonio.sheets(id) ON DELETE CASCADE,
    spot_index integer NOT NULL,
    sigma_deg  double precision,
    rho_s      double precision,
    rho_d      double precision,
    c00 double precision NOT NULL, c01 double precision NOT NULL, c02 double precision NOT NULL,
    c10 double precision NOT NULL, c11 double precision NOT NULL, c12 double precision NOT NULL,
    c20 double precision NOT NULL, c21 double precision NOT NULL, c22 double precision NOT NULL,
    PRIMARY KEY (sheet_id, spot_index)
);
CREATE TABLE gonio.validations (
    identity text PRIMARY KEY,
    value    text NOT NULL
);
CREATE TABLE gonio.population_cache (
    key   text PRIMARY KEY,
    value text NOT NULL
);
CREATE TABLE gonio.audit (
    entry             bigint GENERATED ALWAYS AS IDENTITY PRIMARY KEY,
    at                timestamptz NOT NULL,
    db_user           text NOT NULL,
    os_user           text,
    host              text,
    gonio_version     text NOT NULL,
    action            text NOT NULL CHECK (action IN (ACTIONS)),
    stock             text,
    session_sha256    text,
    instrument_serial text,
    detail            text NOT NULL
);
CREATE FUNCTION gonio.audit_stamp() RETURNS trigger LANGUAGE plpgsql AS $$
BEGIN
    NEW.at := now();
    NEW.db_user := session_user;
    RETURN NEW;
END $$;
CREATE TRIGGER audit_stamp BEFORE INSERT ON gonio.audit
    FOR EACH ROW EXECUTE FUNCTION gonio.audit_stamp();
CREATE FUNCTION gonio.audit_is_append_only() RETURNS trigger LANGUAGE plpgsql AS $$
BEGIN
    RAISE EXCEPTION 'the audit trail is append-only' USING ERRCODE = 'insufficient_privilege';
END $$;
CREATE TRIGGER audit_no_change BEFORE UPDATE OR DELETE ON gonio.audit
    FOR EACH ROW EXECUTE FUNCTION gonio.audit_is_append_only();
CREATE TRIGGER audit_no_truncate BEFORE TRUNCATE ON gonio.audit
    FOR EACH STATEMENT EXECUTE FUNCTION gonio.audit_is_append_only();
DO $$ BEGIN CREATE ROLE gonio_examiner NOLOGIN; EXCEPTION WHEN duplicate_object OR unique_violation THEN NULL; END $$;
DO $$ BEGIN CREATE ROLE gonio_curator NOLOGIN; EXCEPTION WHEN duplicate_object OR unique_violation THEN NULL; END $$;
GRANT gonio_examiner TO gonio_curator;
REVOKE ALL ON SCHEMA gonio FROM PUBLIC;
GRANT USAGE ON SCHEMA gonio TO gonio_examiner;
GRANT SELECT ON ALL TABLES IN SCHEMA gonio TO gonio_examiner;
GRANT INSERT, UPDATE, DELETE ON gonio.population_cache TO gonio_examiner;
GRANT INSERT, UPDATE, DELETE ON gonio.stocks, gonio.sheets, gonio.spots, gonio.validations TO gonio_curator;
GRANT INSERT ON gonio.audit TO gonio_curator;
"#;

/// Every column gonio reads, with its type as `information_schema` names it: checked when
/// a library is opened.
const COLUMNS: &[(&str, &str, &str)] = &[
    ("meta", "key", "text"),
    ("meta", "value", "text"),
    ("stocks", "id", "bigint"),
    ("stocks", "name", "text"),
    ("stocks", "manufacturer", "text"),
    ("stocks", "notes", "text"),
    ("sheets", "id", "bigint"),
    ("sheets", "stock_id", "bigint"),
    ("sheets", "lot", "text"),
    ("sheets", "measured_at", "text"),
    ("sheets", "instrument_serial", "text"),
    ("sheets", "session_path", "text"),
    ("sheets", "session_sha256", "text"),
    ("sheets", "sample", "text"),
    ("sheets", "added_at", "text"),
    ("sheets", "orientation", "text"),
    ("sheets", "side", "text"),
    ("spots", "sheet_id", "bigint"),
    ("spots", "spot_index", "integer"),
    ("spots", "sigma_deg", "double precision"),
    ("spots", "rho_s", "double precision"),
    ("spots", "rho_d", "double precision"),
    ("spots", "c00", "double precision"),
    ("spots", "c01", "double precision"),
    ("spots", "c02", "double precision"),
    ("spots", "c10", "double precision"),
    ("spots", "c11", "double precision"),
    ("spots", "c12", "double precision"),
    ("spots", "c20", "double precision"),
    ("spots", "c21", "double precision"),
    ("spots", "c22", "double precision"),
    ("validations", "identity", "text"),
    ("validations", "value", "text"),
    ("population_cache", "key", "text"),
    ("population_cache", "value", "text"),
    ("audit", "entry", "bigint"),
    ("audit", "at", "timestamp with time zone"),
    ("audit", "db_user", "text"),
    ("audit", "os_user", "text"),
    ("audit", "host", "text"),
    ("audit", "gonio_version", "text"),
    ("audit", "action", "text"),
    ("audit", "stock", "text"),
    ("audit", "session_sha256", "text"),
    ("audit", "instrument_serial", "text"),
    ("audit", "detail", "text"),
];

/// An open library in PostgreSQL.
pub(crate) struct PgLibrary {
    // The trait's reads take `&self`; the client's calls take `&mut`. One library is one
    // connection used by one thread at a time, so a RefCell is all the sharing there is.
    client: RefCell<Client>,
    location: Location,
    actor: Actor,
    /// The login (`session_user`), for messages that say whose rights fell short.
    role: String,
}

/// What the opening probe found in the database.
enum Found {
    /// No schema `gonio`: a database with no library yet.
    Empty,
    /// A gonio library of this schema version.
    Library,
}

impl PgLibrary {
    /// Connect to the database of `url` and check what it holds before anything is
    /// written: another program's schema `gonio`, or a newer gonio's, is refused and left
    /// as it is; only [`OpenMode::Add`] creates the library in a database without one.
    pub fn open(url: &str, mode: OpenMode) -> Result<PgLibrary> {
        let location = Location::Postgres(url.to_string());
        let mut config = postgres::Config::from_str(url).map_err(|e| {
            LibraryError::Invalid(format!(
                "{location}: not a PostgreSQL connection URL: {}",
                chain(&e)
            ))
        })?;
        config
            .application_name(&format!("gonio {}", env!("CARGO_PKG_VERSION")))
            .connect_timeout(CONNECT_TIMEOUT);
        let mut client = config.connect(NoTls).map_err(|e| LibraryError::Postgres {
            library: location.clone(),
            what: format!("cannot connect: {}", chain(&e)),
        })?;
        let (role, encoding): (String, String) = client
            .query_one(
                "SELECT session_user::text, current_setting('server_encoding')",
                &[],
            )
            .map(|r| (r.get(0), r.get(1)))
            .map_err(|e| pg_error(&location, "", "reading who is connected", e))?;
        let library = PgLibrary {
            client: RefCell::new(client),
            location,
            actor: Actor::current(),
            role,
        };
        if encoding != "UTF8" {
            return Err(LibraryError::Foreign {
                path: library.location.to_string().into(),
                what: format!(
                    "a database of encoding {encoding}: a library's names are UTF-8 text (create the database with ENCODING 'UTF8')"
                ),
            });
        }
        match library.probe()? {
            Found::Library => Ok(library),
            Found::Empty if mode == OpenMode::Existing => Err(LibraryError::Missing {
                library: library.location.clone(),
            }),
            Found::Empty => {
                library.create_schema()?;
                Ok(library)
            }
        }
    }

    fn error<'a>(&'a self, doing: &'a str) -> impl Fn(postgres::Error) -> LibraryError + 'a {
        move |e| pg_error(&self.location, &self.role, doing, e)
    }

    /// What the database holds, read-only.
    fn probe(&self) -> Result<Found> {
        let mut client = self.client.borrow_mut();
        let row = client
            .query_one(
                "SELECT EXISTS (SELECT 1 FROM pg_namespace WHERE nspname = 'gonio'),
                        to_regclass('gonio.meta') IS NOT NULL",
                &[],
            )
            .map_err(self.error("reading what the database holds"))?;
        let (schema, meta): (bool, bool) = (row.get(0), row.get(1));
        if !schema {
            return Ok(Found::Empty);
        }
        let foreign = |what: String| LibraryError::Foreign {
            path: self.location.to_string().into(),
            what,
        };
        if !meta {
            return Err(foreign(
                "a schema 'gonio' without a gonio library's meta table".into(),
            ));
        }
        let rows = client
            .query(
                "SELECT key, value FROM gonio.meta WHERE key IN ('application_id', 'schema_version')",
                &[],
            )
            .map_err(self.error("reading the library's schema version"))?;
        // Read before the columns are checked: text or nothing, never a panic.
        let value = |key: &str| {
            rows.iter()
                .find(|r| r.try_get::<_, String>(0).ok().as_deref() == Some(key))
                .and_then(|r| r.try_get::<_, String>(1).ok())
        };
        if value("application_id") != Some(APPLICATION_ID.to_string()) {
            return Err(foreign(format!(
                "application id {:?} in gonio.meta, a gonio library's is {APPLICATION_ID}",
                value("application_id")
            )));
        }
        match value("schema_version").and_then(|v| v.parse::<i64>().ok()) {
            Some(v) if v > SCHEMA_VERSION => Err(LibraryError::Newer {
                library: self.location.clone(),
                found: v,
            }),
            Some(v) if v == SCHEMA_VERSION => {
                // Every column gonio reads is of the type it reads: a table changed by
                // other means is refused here, not met as a wrong type mid-search.
                let columns = client
                    .query(
                        "SELECT table_name::text, column_name::text, data_type::text
                         FROM information_schema.columns WHERE table_schema = 'gonio'",
                        &[],
                    )
                    .map_err(self.error("reading the library's tables"))?;
                let found: Vec<(String, String, String)> = columns
                    .iter()
                    .map(|r| (r.get(0), r.get(1), r.get(2)))
                    .collect();
                for (table, column, kind) in COLUMNS {
                    let actual = found
                        .iter()
                        .find(|(t, c, _)| t == table && c == column)
                        .map(|(_, _, k)| k.as_str());
                    if actual != Some(*kind) {
                        return Err(foreign(format!(
                            "gonio.{table}.{column} is {}, a gonio library's is {kind}",
                            actual.unwrap_or("missing")
                        )));
                    }
                }
                Ok(Found::Library)
            }
            // A PostgreSQL library began at schema 3: an older number was not written by
            // gonio.
            v => Err(foreign(format!("schema_version {v:?} in gonio.meta"))),
        }
    }

    /// Make the library's schema, roles and first entry, once: creators queue on an
    /// advisory lock and the second finds the first's tables.
    fn create_schema(&self) -> Result<()> {
        let mut client = self.client.borrow_mut();
        let creating = "creating the library (its schema 'gonio' and the roles gonio_examiner and gonio_curator: the database's owner with CREATEROLE creates it)";
        let mut tx = client.transaction().map_err(self.error(creating))?;
        tx.execute(
            "SELECT pg_advisory_xact_lock($1)",
            &[&i64::from(APPLICATION_ID)],
        )
        .map_err(self.error(creating))?;
        let exists: bool = tx
            .query_one(
                "SELECT EXISTS (SELECT 1 FROM pg_namespace WHERE nspname = 'gonio')",
                &[],
            )
            .map_err(self.error(creating))?
            .get(0);
        if !exists {
            tx.batch_execute(&SCHEMA.replace("ACTIONS", audit::ACTIONS))
                .map_err(self.error(creating))?;
            for (key, value) in [
                ("schema_version", SCHEMA_VERSION.to_string()),
                ("application_id", APPLICATION_ID.to_string()),
                ("created_by", format!("gonio {}", env!("CARGO_PKG_VERSION"))),
                ("created_at", super::now_utc()),
            ] {
                tx.execute(
                    "INSERT INTO gonio.meta (key, value) VALUES ($1, $2)",
                    &[&key, &value],
                )
                .map_err(self.error(creating))?;
            }
            self.append(
                &mut tx,
                &audit::event("create", serde_json::json!({ "schema": SCHEMA_VERSION })),
            )
            .map_err(self.error(creating))?;
        }
        tx.commit().map_err(self.error(creating))
    }

    /// A change's transaction, holding the library's one change lock until it ends (see
    /// the module's comment). An examiner's change is refused here, before anything.
    fn write<'c>(&self, client: &'c mut Client, doing: &str) -> Result<Transaction<'c>> {
        let mut tx = client.transaction().map_err(self.error(doing))?;
        tx.batch_execute("LOCK TABLE gonio.stocks IN SHARE ROW EXCLUSIVE MODE")
            .map_err(self.error(doing))?;
        Ok(tx)
    }

    /// A read-only transaction of one snapshot (REPEATABLE READ): its reads see one state
    /// of the library, whatever commits meanwhile.
    fn snapshot<'c>(&self, client: &'c mut Client, doing: &str) -> Result<Transaction<'c>> {
        client
            .build_transaction()
            .isolation_level(IsolationLevel::RepeatableRead)
            .read_only(true)
            .start()
            .map_err(self.error(doing))
    }

    /// Append one entry to the trail in the change's transaction `tx` (the database
    /// stamps its time and role).
    fn append(&self, tx: &mut Transaction<'_>, entry: &NewEntry) -> Result<(), postgres::Error> {
        tx.execute(
            "INSERT INTO gonio.audit (at, db_user, os_user, host, gonio_version, action, stock, session_sha256, instrument_serial, detail)
             VALUES (now(), session_user, $1, $2, $3, $4, $5, $6, $7, $8)",
            &[
                &self.actor.os_user,
                &self.actor.host,
                &self.actor.gonio_version,
                &entry.action,
                &entry.stock,
                &entry.session_sha256,
                &entry.instrument_serial,
                &entry.detail.to_string(),
            ],
        )?;
        Ok(())
    }

    /// Delete the sheet of row `sheet_id` with its spots, and say so in the trail.
    fn delete_sheet(
        &self,
        tx: &mut Transaction<'_>,
        sheet_id: i64,
    ) -> Result<usize, postgres::Error> {
        let row = tx.query_one(
            "SELECT h.session_sha256, s.name, h.lot, h.instrument_serial FROM gonio.sheets h JOIN gonio.stocks s ON h.stock_id = s.id WHERE h.id = $1",
            &[&sheet_id],
        )?;
        let (sha, instrument): (String, String) = (row.get(0), row.get(3));
        let spots = tx
            .query(
                "SELECT sigma_deg, rho_s, rho_d, c00, c01, c02, c10, c11, c12, c20, c21, c22
                 FROM gonio.spots WHERE sheet_id = $1 ORDER BY spot_index",
                &[&sheet_id],
            )?
            .iter()
            .map(|r| spot(r, 0))
            .collect::<Result<Vec<_>, _>>()?;
        let sheet = LibrarySheet {
            stock: row.get(1),
            lot: row.get(2),
            instrument: Some(instrument.clone()),
            sheet: Sheet { spots },
        };
        self.append(tx, &audit::removed(&sha, Some(&instrument), &sheet))?;
        tx.execute("DELETE FROM gonio.sheets WHERE id = $1", &[&sheet_id])?;
        Ok(sheet.sheet.spots.len())
    }

    /// Insert the sessions of an exchange file not yet in the library, in the change's
    /// transaction `tx`, each with an `import` entry when `audited`.
    fn insert_sessions(
        &self,
        tx: &mut Transaction<'_>,
        file: &ExchangeFile,
        audited: bool,
    ) -> Result<ImportCounts> {
        let doing = "importing";
        let mut counts = ImportCounts {
            records: file.records(),
            ..Default::default()
        };
        for session in &file.sessions {
            let present: bool = tx
                .query_one(
                    "SELECT EXISTS (SELECT 1 FROM gonio.sheets WHERE session_sha256 = $1)",
                    &[&session.sheet.session_sha256],
                )
                .map_err(self.error(doing))?
                .get(0);
            if present {
                counts.sessions_skipped += 1;
                continue;
            }
            let (stock_id, new) =
                upsert_stock(tx, &session.stock).map_err(|e| e.into_library(self, doing))?;
            counts.stocks_added += usize::from(new);
            let what = format!("{}:{}", file.path.display(), session.first_line);
            insert_sheet(tx, stock_id, &session.sheet, &what)
                .map_err(|e| e.into_library(self, doing))?;
            if audited {
                self.append(
                    tx,
                    &audit::added("import", &session.stock.name, &session.sheet),
                )
                .map_err(self.error(doing))?;
            }
            counts.sessions_added += 1;
        }
        Ok(counts)
    }

    fn text_value(&self, sql: &str, key: &str, doing: &str) -> Result<Option<serde_json::Value>> {
        let row = self
            .client
            .borrow_mut()
            .query_opt(sql, &[&key])
            .map_err(self.error(doing))?;
        Ok(row.and_then(|r| serde_json::from_str(&r.get::<_, String>(0)).ok()))
    }
}

impl Store for PgLibrary {
    fn location(&self) -> &Location {
        &self.location
    }

    fn add_sheets(&mut self, stock: &StockInfo, sheets: &[SheetRecord]) -> Result<()> {
        store::check_add(stock, sheets)?;
        let doing = "adding sheets";
        let mut client = self.client.borrow_mut();
        let mut tx = self.write(&mut client, doing)?;
        let (stock_id, _) =
            upsert_stock(&mut tx, stock).map_err(|e| e.into_library(self, doing))?;
        for sheet in sheets {
            insert_sheet(&mut tx, stock_id, sheet, &sheet.session_path)
                .map_err(|e| e.into_library(self, doing))?;
            self.append(&mut tx, &audit::added("add", &stock.name, sheet))
                .map_err(self.error(doing))?;
        }
        tx.commit().map_err(self.error(doing))
    }

    fn stock_of_session(&self, sha256: &str) -> Result<Option<String>> {
        let row = self
            .client
            .borrow_mut()
            .query_opt(
                "SELECT s.name FROM gonio.sheets h JOIN gonio.stocks s ON h.stock_id = s.id WHERE h.session_sha256 = $1",
                &[&sha256],
            )
            .map_err(self.error("reading the library"))?;
        Ok(row.map(|r| r.get(0)))
    }

    fn stocks(&self) -> Result<Vec<StockSummary>> {
        let rows = self
            .client
            .borrow_mut()
            .query(
                r#"SELECT s.name, s.manufacturer, s.notes,
                        (SELECT count(*) FROM gonio.sheets h WHERE h.stock_id = s.id),
                        (SELECT count(*) FROM gonio.spots p JOIN gonio.sheets h ON p.sheet_id = h.id WHERE h.stock_id = s.id)
                 FROM gonio.stocks s ORDER BY s.name COLLATE "C""#,
                &[],
            )
            .map_err(self.error("listing the stocks"))?;
        Ok(rows
            .iter()
            .map(|r| StockSummary {
                name: r.get(0),
                manufacturer: r.get(1),
                notes: r.get(2),
                sheets: count(r.get(3)),
                spots: count(r.get(4)),
            })
            .collect())
    }

    fn remove_stock(&mut self, name: &str) -> Result<Removed> {
        let doing = "removing a stock";
        let mut client = self.client.borrow_mut();
        let mut tx = self.write(&mut client, doing)?;
        let Some(id) = tx
            .query_opt("SELECT id FROM gonio.stocks WHERE name = $1", &[&name])
            .map_err(self.error(doing))?
            .map(|r| r.get::<_, i64>(0))
        else {
            return Err(LibraryError::UnknownStock {
                library: self.location.clone(),
                name: name.to_string(),
            });
        };
        let sheets: Vec<(i64, String)> = tx
            .query(
                r#"SELECT id, session_sha256 FROM gonio.sheets WHERE stock_id = $1 ORDER BY session_sha256 COLLATE "C""#,
                &[&id],
            )
            .map_err(self.error(doing))?
            .iter()
            .map(|r| (r.get(0), r.get(1)))
            .collect();
        let mut spots = 0;
        for (sheet_id, _) in &sheets {
            spots += self
                .delete_sheet(&mut tx, *sheet_id)
                .map_err(self.error(doing))?;
        }
        tx.execute("DELETE FROM gonio.stocks WHERE id = $1", &[&id])
            .map_err(self.error(doing))?;
        tx.commit().map_err(self.error(doing))?;
        Ok(Removed {
            stocks: vec![name.to_string()],
            sessions: sheets.into_iter().map(|(_, sha)| sha).collect(),
            spots,
        })
    }

    fn remove_session(&mut self, sha256_prefix: &str) -> Result<Removed> {
        let prefix = store::session_prefix(&self.location, sha256_prefix)?;
        let doing = "removing a session";
        let mut client = self.client.borrow_mut();
        let mut tx = self.write(&mut client, doing)?;
        // Hex digits only, so the prefix holds no LIKE wildcards.
        let matches: Vec<((i64, i64), String)> = tx
            .query(
                r#"SELECT id, stock_id, session_sha256 FROM gonio.sheets WHERE session_sha256 LIKE $1 || '%' ORDER BY session_sha256 COLLATE "C""#,
                &[&prefix],
            )
            .map_err(self.error(doing))?
            .iter()
            .map(|r| ((r.get(0), r.get(1)), r.get(2)))
            .collect();
        let ((sheet_id, stock_id), sha256) = store::one_session(&self.location, &prefix, &matches)?;
        let spots = self
            .delete_sheet(&mut tx, sheet_id)
            .map_err(self.error(doing))?;
        let left: i64 = tx
            .query_one(
                "SELECT count(*) FROM gonio.sheets WHERE stock_id = $1",
                &[&stock_id],
            )
            .map_err(self.error(doing))?
            .get(0);
        let mut stocks = Vec::new();
        if left == 0 {
            let name: String = tx
                .query_one(
                    "DELETE FROM gonio.stocks WHERE id = $1 RETURNING name",
                    &[&stock_id],
                )
                .map_err(self.error(doing))?
                .get(0);
            stocks.push(name);
        }
        tx.commit().map_err(self.error(doing))?;
        Ok(Removed {
            stocks,
            sessions: vec![sha256],
            spots,
        })
    }

    fn for_each_record(&self, each: &mut dyn FnMut(ExchangeRecord) -> Result<()>) -> Result<()> {
        let doing = "reading the records";
        let mut client = self.client.borrow_mut();
        // One snapshot for the whole stream: an export is one state of the library.
        let mut tx = self.snapshot(&mut client, doing)?;
        let mut rows = tx
            .query_raw(
                r#"SELECT s.name, s.manufacturer, s.notes, h.session_sha256, h.sample, h.lot, h.measured_at, h.instrument_serial,
                        h.session_path, h.added_at, p.spot_index,
                        (SELECT count(*) FROM gonio.spots q WHERE q.sheet_id = h.id),
                        p.sigma_deg, p.rho_s, p.rho_d, p.c00, p.c01, p.c02, p.c10, p.c11, p.c12, p.c20, p.c21, p.c22,
                        h.orientation, h.side
                 FROM gonio.spots p JOIN gonio.sheets h ON p.sheet_id = h.id JOIN gonio.stocks s ON h.stock_id = s.id
                 ORDER BY s.name COLLATE "C", h.session_sha256 COLLATE "C", p.spot_index"#,
                std::iter::empty::<&str>(),
            )
            .map_err(self.error(doing))?;
        while let Some(r) = rows.next().map_err(self.error(doing))? {
            let record = (|| -> Result<ExchangeRecord, postgres::Error> {
                let covariance = spot(&r, 12)?.covariance;
                Ok(ExchangeRecord {
                    schema: crate::schema::LIBRARY_RECORD.to_string(),
                    stock: r.try_get(0)?,
                    manufacturer: r.try_get(1)?,
                    stock_notes: r.try_get(2)?,
                    session_sha256: r.try_get(3)?,
                    sample: r.try_get(4)?,
                    lot: r.try_get(5)?,
                    measured_at: r.try_get(6)?,
                    orientation: orientation(r.try_get(24)?),
                    side: side(r.try_get(25)?),
                    instrument_serial: r.try_get(7)?,
                    session_path: r.try_get(8)?,
                    added_at: r.try_get(9)?,
                    spot: count(i64::from(r.try_get::<_, i32>(10)?)),
                    spots: count(r.try_get(11)?),
                    sigma_deg: r.try_get(12)?,
                    rho_s: r.try_get(13)?,
                    rho_d: r.try_get(14)?,
                    covariance,
                })
            })()
            .map_err(self.error(doing))?;
            each(record)?;
        }
        drop(rows);
        tx.commit().map_err(self.error(doing))
    }

    fn has_session(&self, sha256: &str) -> Result<bool> {
        Ok(self
            .client
            .borrow_mut()
            .query_one(
                "SELECT EXISTS (SELECT 1 FROM gonio.sheets WHERE session_sha256 = $1)",
                &[&sha256],
            )
            .map_err(self.error("reading the library"))?
            .get(0))
    }

    fn sheet_count(&self) -> Result<usize> {
        Ok(count(
            self.client
                .borrow_mut()
                .query_one("SELECT count(*) FROM gonio.sheets", &[])
                .map_err(self.error("reading the library"))?
                .get(0),
        ))
    }

    fn import(&mut self, file: &ExchangeFile) -> Result<ImportCounts> {
        let doing = "importing";
        let mut client = self.client.borrow_mut();
        let mut tx = self.write(&mut client, doing)?;
        let counts = self.insert_sessions(&mut tx, file, true)?;
        tx.commit().map_err(self.error(doing))?;
        Ok(counts)
    }

    fn record_validation(&mut self, identity: &str, population: &serde_json::Value) -> Result<()> {
        let doing = "recording a validation";
        let mut client = self.client.borrow_mut();
        let mut tx = self.write(&mut client, doing)?;
        tx.execute(
            "INSERT INTO gonio.validations (identity, value) VALUES ($1, $2)
             ON CONFLICT (identity) DO UPDATE SET value = EXCLUDED.value",
            &[&identity, &store::validation_value(population).to_string()],
        )
        .map_err(self.error(doing))?;
        self.append(&mut tx, &audit::validated(identity))
            .map_err(self.error(doing))?;
        tx.commit().map_err(self.error(doing))
    }

    fn validation_record(&self, identity: &str) -> Result<Option<serde_json::Value>> {
        self.text_value(
            "SELECT value FROM gonio.validations WHERE identity = $1",
            identity,
            "reading a recorded validation",
        )
    }

    fn validation_records(&self) -> Result<Vec<(String, serde_json::Value)>> {
        let rows = self
            .client
            .borrow_mut()
            .query(
                r#"SELECT identity, value FROM gonio.validations ORDER BY identity COLLATE "C""#,
                &[],
            )
            .map_err(self.error("reading the recorded validations"))?;
        Ok(rows
            .iter()
            .filter_map(|r| Some((r.get(0), serde_json::from_str(&r.get::<_, String>(1)).ok()?)))
            .collect())
    }

    fn contents(&self) -> Result<Contents> {
        let doing = "reading the library's sheets";
        let mut client = self.client.borrow_mut();
        let mut tx = self.snapshot(&mut client, doing)?;
        let mut contents = read_contents(&mut tx).map_err(self.error(doing))?;
        contents.last_entry = tx
            .query_one("SELECT max(entry) FROM gonio.audit", &[])
            .map_err(self.error(doing))?
            .get(0);
        tx.commit().map_err(self.error(doing))?;
        Ok(contents)
    }

    fn cached_population(&self, identity: &str) -> Result<Option<serde_json::Value>> {
        self.text_value(
            "SELECT value FROM gonio.population_cache WHERE key = $1",
            &population_cache_key(identity),
            "reading the cached population",
        )
    }

    fn cache_population(&mut self, identity: &str, population: &serde_json::Value) -> Result<()> {
        let doing = "caching the population";
        let key = population_cache_key(identity);
        let mut client = self.client.borrow_mut();
        let mut tx = client.transaction().map_err(self.error(doing))?;
        tx.execute(
            "DELETE FROM gonio.population_cache WHERE key <> $1",
            &[&key],
        )
        .map_err(self.error(doing))?;
        tx.execute(
            "INSERT INTO gonio.population_cache (key, value) VALUES ($1, $2)
             ON CONFLICT (key) DO UPDATE SET value = EXCLUDED.value",
            &[&key, &population.to_string()],
        )
        .map_err(self.error(doing))?;
        tx.commit().map_err(self.error(doing))
    }

    fn history(&self, each: &mut dyn FnMut(AuditEntry) -> Result<()>) -> Result<()> {
        let doing = "reading the audit trail";
        let mut client = self.client.borrow_mut();
        let mut rows = client
            .query_raw(
                r#"SELECT entry, to_char(at AT TIME ZONE 'UTC', 'YYYY-MM-DD"T"HH24:MI:SS.MS"Z"'),
                        db_user, os_user, host, gonio_version, action, stock, session_sha256, instrument_serial, detail
                 FROM gonio.audit ORDER BY entry"#,
                std::iter::empty::<&str>(),
            )
            .map_err(self.error(doing))?;
        while let Some(r) = rows.next().map_err(self.error(doing))? {
            let detail: String = r.get(10);
            each(AuditEntry {
                entry: r.get(0),
                at: r.get(1),
                db_user: r.get(2),
                os_user: r.get(3),
                host: r.get(4),
                gonio_version: r.get(5),
                action: r.get(6),
                stock: r.get(7),
                session_sha256: r.get(8),
                instrument_serial: r.get(9),
                detail: serde_json::from_str(&detail).unwrap_or(serde_json::Value::String(detail)),
            })?;
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
        let doing = "migrating into the library";
        let source = from.to_string();
        let mut client = self.client.borrow_mut();
        let mut tx = self.write(&mut client, doing)?;
        for entry in history {
            self.append(&mut tx, &audit::migrated(entry, &source))
                .map_err(self.error(doing))?;
        }
        let counts = self.insert_sessions(&mut tx, file, false)?;
        for (identity, value) in validations {
            tx.execute(
                "INSERT INTO gonio.validations (identity, value) VALUES ($1, $2)",
                &[identity, &value.to_string()],
            )
            .map_err(self.error(doing))?;
        }
        let entry = audit::event(
            "migrate",
            serde_json::json!({ "from": source, "sessions": counts.sessions_added, "records": counts.records, "audit_entries": history.len(), "validations": validations.len() }),
        );
        self.append(&mut tx, &entry).map_err(self.error(doing))?;
        tx.commit().map_err(self.error(doing))
    }
}

/// Every sheet with its lay and spots, in the export's order (see [`Contents`]).
fn read_contents(tx: &mut Transaction<'_>) -> Result<Contents, postgres::Error> {
    let mut index = std::collections::HashMap::new();
    let mut sheets: Vec<SheetRows> = Vec::new();
    for r in tx.query(
        "SELECT h.id, s.name, h.session_sha256, h.lot, h.instrument_serial, h.orientation, h.side
         FROM gonio.sheets h JOIN gonio.stocks s ON h.stock_id = s.id",
        &[],
    )? {
        index.insert(r.try_get::<_, i64>(0)?, sheets.len());
        sheets.push(SheetRows {
            sha256: r.try_get(2)?,
            sheet: LibrarySheet {
                stock: r.try_get(1)?,
                lot: r.try_get(3)?,
                instrument: Some(r.try_get(4)?),
                sheet: Sheet::default(),
            },
            lay: SheetLay {
                orientation: orientation(r.try_get(5)?),
                side: side(r.try_get(6)?),
            },
            spots: Vec::new(),
        });
    }
    let mut rows = tx.query_raw(
        "SELECT sheet_id, spot_index, sigma_deg, rho_s, rho_d, c00, c01, c02, c10, c11, c12, c20, c21, c22
         FROM gonio.spots",
        std::iter::empty::<&str>(),
    )?;
    while let Some(r) = rows.next()? {
        let Some(&k) = index.get(&r.try_get::<_, i64>(0)?) else {
            continue;
        };
        let index = i64::from(r.try_get::<_, i32>(1)?);
        sheets[k].spots.push((index, spot(&r, 2)?));
    }
    Ok(Contents {
        sheets: in_export_order(sheets),
        last_entry: None,
    })
}

/// The spot of the 12 columns from `first`: σ, ρs, ρd and the covariance row by row.
fn spot(row: &Row, first: usize) -> Result<Spot, postgres::Error> {
    let mut covariance = [[0.0; 3]; 3];
    for (i, line) in covariance.iter_mut().enumerate() {
        for (j, c) in line.iter_mut().enumerate() {
            *c = row.try_get(first + 3 + 3 * i + j)?;
        }
    }
    Ok(Spot {
        values: [
            row.try_get(first)?,
            row.try_get(first + 1)?,
            row.try_get(first + 2)?,
        ],
        covariance,
    })
}

/// The table's CHECK admits only these, or NULL (unknown).
fn orientation(text: Option<String>) -> Option<Orientation> {
    match text.as_deref() {
        Some("md") => Some(Orientation::Md),
        Some("cd") => Some(Orientation::Cd),
        _ => None,
    }
}

/// As [`orientation`].
fn side(text: Option<String>) -> Option<Side> {
    match text.as_deref() {
        Some("felt") => Some(Side::Felt),
        Some("wire") => Some(Side::Wire),
        _ => None,
    }
}

/// A count (bigint, never negative from count(*) or a CHECKed index).
fn count(value: i64) -> usize {
    usize::try_from(value).unwrap_or(0)
}

/// An error inside a change: the library's own, or the server's.
enum TxError {
    Library(LibraryError),
    Postgres(postgres::Error),
}

impl From<postgres::Error> for TxError {
    fn from(e: postgres::Error) -> TxError {
        TxError::Postgres(e)
    }
}

impl TxError {
    fn into_library(self, library: &PgLibrary, doing: &str) -> LibraryError {
        match self {
            TxError::Library(e) => e,
            TxError::Postgres(e) => library.error(doing)(e),
        }
    }
}

/// The stock's id (and whether it is new), made when new; manufacturer and notes given
/// fill the library's when it has none, and must agree when it has.
fn upsert_stock(tx: &mut Transaction<'_>, stock: &StockInfo) -> Result<(i64, bool), TxError> {
    let row = tx.query_opt(
        "SELECT id, manufacturer, notes FROM gonio.stocks WHERE name = $1",
        &[&stock.name],
    )?;
    let Some(row) = row else {
        let id: i64 = tx
            .query_one(
                "INSERT INTO gonio.stocks (name, manufacturer, notes) VALUES ($1, $2, $3) RETURNING id",
                &[&stock.name, &stock.manufacturer, &stock.notes],
            )?
            .get(0);
        return Ok((id, true));
    };
    let id: i64 = row.get(0);
    for (field, given) in
        store::stock_fields_to_fill(stock, &row.get(1), &row.get(2)).map_err(TxError::Library)?
    {
        // `field` is one of two fixed column names, never user text.
        tx.execute(
            &format!("UPDATE gonio.stocks SET {field} = $1 WHERE id = $2"),
            &[&given, &id],
        )?;
    }
    Ok((id, false))
}

/// Insert one sheet and its spots (one statement for all of them); a session already
/// present is [`LibraryError::Duplicate`] naming its stock.
fn insert_sheet(
    tx: &mut Transaction<'_>,
    stock_id: i64,
    sheet: &SheetRecord,
    what: &str,
) -> Result<(), TxError> {
    let present = tx.query_opt(
        "SELECT s.name FROM gonio.sheets h JOIN gonio.stocks s ON h.stock_id = s.id WHERE h.session_sha256 = $1",
        &[&sheet.session_sha256],
    )?;
    if let Some(row) = present {
        return Err(TxError::Library(LibraryError::Duplicate {
            what: what.to_string(),
            sha256: sheet.session_sha256.clone(),
            stock: row.get(0),
        }));
    }
    let sheet_id: i64 = tx
        .query_one(
            "INSERT INTO gonio.sheets (stock_id, lot, measured_at, instrument_serial, session_path, session_sha256, sample, added_at, orientation, side)
             VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9, $10) RETURNING id",
            &[
                &stock_id,
                &sheet.lot,
                &sheet.measured_at,
                &sheet.instrument_serial,
                &sheet.session_path,
                &sheet.session_sha256,
                &sheet.sample,
                &sheet.added_at,
                &sheet.lay.orientation.map(Orientation::name),
                &sheet.lay.side.map(Side::name),
            ],
        )?
        .get(0);
    let index: Vec<i32> = (0..sheet.spots.len())
        .map(|k| i32::try_from(k).unwrap_or(i32::MAX))
        .collect();
    let value =
        |i: usize| -> Vec<Option<f64>> { sheet.spots.iter().map(|s| s.values[i]).collect() };
    let covariance = |i: usize, j: usize| -> Vec<f64> {
        sheet.spots.iter().map(|s| s.covariance[i][j]).collect()
    };
    let (v0, v1, v2) = (value(0), value(1), value(2));
    let c: Vec<Vec<f64>> = (0..9).map(|k| covariance(k / 3, k % 3)).collect();
    tx.execute(
        "INSERT INTO gonio.spots (sheet_id, spot_index, sigma_deg, rho_s, rho_d, c00, c01, c02, c10, c11, c12, c20, c21, c22)
         SELECT $1, * FROM unnest($2::integer[], $3::float8[], $4::float8[], $5::float8[],
                                  $6::float8[], $7::float8[], $8::float8[], $9::float8[], $10::float8[],
                                  $11::float8[], $12::float8[], $13::float8[], $14::float8[])",
        &[
            &sheet_id, &index, &v0, &v1, &v2, &c[0], &c[1], &c[2], &c[3], &c[4], &c[5], &c[6],
            &c[7], &c[8],
        ],
    )?;
    Ok(())
}

/// An error of the server as the library's: a refusal for want of a right is
/// [`LibraryError::Denied`], naming the login and the role that has the right.
fn pg_error(location: &Location, role: &str, doing: &str, e: postgres::Error) -> LibraryError {
    let Some(db) = e.as_db_error() else {
        return LibraryError::Postgres {
            library: location.clone(),
            what: format!("{doing}: {}", chain(&e)),
        };
    };
    let mut said = db.message().to_string();
    if let Some(detail) = db.detail() {
        said.push_str(&format!(" ({detail})"));
    }
    if let Some(hint) = db.hint() {
        said.push_str(&format!("; hint: {hint}"));
    }
    if *db.code() == SqlState::INSUFFICIENT_PRIVILEGE {
        return LibraryError::Denied {
            library: location.clone(),
            what: format!(
                "{doing} is not allowed to role '{role}' (the database said: {said}). Adding, removing and validating stocks is for members of {CURATOR_ROLE}; searching, comparing, listing and exporting for members of {EXAMINER_ROLE}. The library's administrator grants them (GRANT {CURATOR_ROLE} TO {role})"
            ),
        };
    }
    LibraryError::Postgres {
        library: location.clone(),
        what: format!("{doing}: {said}"),
    }
}

/// An error with its causes, as one line (the client's own text is only its kind).
fn chain(e: &dyn std::error::Error) -> String {
    let mut text = e.to_string();
    let mut source = e.source();
    while let Some(cause) = source {
        let cause_text = cause.to_string();
        if !text.contains(&cause_text) {
            text.push_str(": ");
            text.push_str(&cause_text);
        }
        source = cause.source();
    }
    text
}
