//! The library on a real PostgreSQL server (issue 29): the one `.ci/run` starts
//! (`.ci/postgres`), named by `GONIO_TEST_POSTGRES` (an administrator's URL). Without it
//! these tests say so (NOTICE) and pass, as the browser tests do without chromium;
//! `GONIO_REQUIRE_POSTGRES=1` (set by `.ci/run`) makes a missing server a failure.
//!
//! Each test makes a database of its own, and logins of its own for the roles.
use super::tests::{export_bytes, filled_at, sheet, stock};
use super::*;
use ::postgres::NoTls;
use std::sync::atomic::{AtomicUsize, Ordering};

/// The administrator's URL of the test server, or `None` (with a notice) when there is none.
pub(crate) fn server() -> Option<String> {
    match std::env::var("GONIO_TEST_POSTGRES") {
        Ok(url) if !url.is_empty() => Some(url),
        _ => {
            assert!(
                std::env::var("GONIO_REQUIRE_POSTGRES").as_deref() != Ok("1"),
                "GONIO_REQUIRE_POSTGRES=1 but GONIO_TEST_POSTGRES names no server (.ci/postgres start DIR prints one)"
            );
            eprintln!(
                "NOTICE: no PostgreSQL server (GONIO_TEST_POSTGRES unset): the library's PostgreSQL tests are left out"
            );
            None
        }
    }
}

/// `url` with its user and database replaced.
pub(crate) fn url_of(admin: &str, user: &str, database: &str) -> String {
    let (scheme, rest) = admin.split_once("://").expect("a URL");
    let (authority, tail) = rest.split_at(rest.find('/').expect("a database in the URL"));
    let host = authority.rsplit_once('@').map_or(authority, |(_, h)| h);
    let query = tail
        .split_once('?')
        .map(|(_, q)| format!("?{q}"))
        .unwrap_or_default();
    format!("{scheme}://{user}@{host}/{database}{query}")
}

/// A database of its own for one test, dropped with it.
pub(crate) struct TestDatabase {
    admin: String,
    /// Its name.
    pub name: String,
    /// The logins made for it (roles are the server's, not the database's: dropped too).
    logins: std::sync::Mutex<Vec<String>>,
}

static COUNTER: AtomicUsize = AtomicUsize::new(0);

impl TestDatabase {
    /// A new, empty database (UTF-8) on the server of `admin`.
    pub fn new(admin: &str) -> TestDatabase {
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.subsec_nanos());
        let name = format!(
            "gonio_test_{}_{}_{nanos}",
            std::process::id(),
            COUNTER.fetch_add(1, Ordering::Relaxed)
        );
        let mut client = ::postgres::Client::connect(admin, NoTls).expect("the test server");
        client
            .batch_execute(&format!(
                "CREATE DATABASE {name} ENCODING 'UTF8' TEMPLATE template0"
            ))
            .expect("create a database");
        TestDatabase {
            admin: admin.to_string(),
            name,
            logins: Default::default(),
        }
    }

    /// The administrator's URL of this database.
    pub fn admin_url(&self) -> String {
        let user = self
            .admin
            .split_once("://")
            .and_then(|(_, rest)| rest.split_once('@'))
            .map_or("postgres", |(user, _)| {
                user.split(':').next().unwrap_or(user)
            });
        url_of(&self.admin, user, &self.name)
    }

    /// A new login of this test, member of `role` (or of none), and its URL to this database.
    pub fn login(&self, role: Option<&str>) -> String {
        let user = format!("{}_{}", self.name, COUNTER.fetch_add(1, Ordering::Relaxed));
        let mut client = ::postgres::Client::connect(&self.admin, NoTls).expect("the test server");
        let member = role.map(|r| format!(" IN ROLE {r}")).unwrap_or_default();
        client
            .batch_execute(&format!("CREATE ROLE {user} LOGIN{member}"))
            .expect("create a login");
        self.logins.lock().expect("logins").push(user.clone());
        url_of(&self.admin, &user, &self.name)
    }

    /// The location of this database as the administrator (its owner).
    pub fn location(&self) -> Location {
        Location::Postgres(self.admin_url())
    }
}

impl Drop for TestDatabase {
    fn drop(&mut self) {
        if let Ok(mut client) = ::postgres::Client::connect(&self.admin, NoTls) {
            let _ = client.batch_execute(&format!(
                "DROP DATABASE IF EXISTS {} WITH (FORCE)",
                self.name
            ));
            for login in self.logins.lock().map(|l| l.clone()).unwrap_or_default() {
                let _ = client.batch_execute(&format!("DROP ROLE IF EXISTS {login}"));
            }
        }
    }
}

#[test]
fn a_postgresql_library_keeps_what_the_file_keeps() {
    let Some(admin) = server() else { return };
    let db = TestDatabase::new(&admin);
    let dir = tempfile::tempdir().expect("temp dir");
    let file = filled_at(&Location::File(dir.path().join("library.sqlite")));
    let mut pg = filled_at(&db.location());
    assert_eq!(
        export_bytes(&pg),
        export_bytes(&file),
        "the same export, byte for byte"
    );
    assert_eq!(pg.stocks().expect("stocks"), file.stocks().expect("stocks"));
    assert_eq!(pg.sheets().expect("sheets"), file.sheets().expect("sheets"));
    assert_eq!(pg.lays().expect("lays"), file.lays().expect("lays"));
    // The same refusals.
    let err = pg
        .add_sheets(&stock("Other"), &[sheet(1, 1)])
        .expect_err("a session twice");
    assert!(
        matches!(err, LibraryError::Duplicate { ref stock, .. } if stock == "PPC"),
        "{err}"
    );
    let err = Library::open(&db.location(), OpenMode::Existing)
        .expect("reopen")
        .remove_session("zz")
        .expect_err("not hex");
    assert!(matches!(err, LibraryError::SessionPrefix { .. }), "{err}");
    // Removal, then the trail recovers every state.
    let removed = pg.remove_stock("Bond 80 g/m²").expect("remove");
    assert_eq!(removed.sessions.len(), 1);
    let trail = pg.audit_entries().expect("history");
    let actions: Vec<&str> = trail.iter().map(|e| e.action.as_str()).collect();
    assert_eq!(actions, ["create", "add", "add", "add", "add", "remove"]);
    assert!(
        trail
            .iter()
            .all(|e| e.db_user.as_deref() == Some("postgres")),
        "the database stamps its role: {trail:?}"
    );
    assert_eq!(
        pg.contents_at(5).expect("replay").identity,
        crate::analysis::evidence::population::contents_identity(
            &file
                .sheets()
                .expect("sheets")
                .into_iter()
                .map(|(_, s)| s)
                .collect::<Vec<_>>()
        ),
        "before the removal, the file's contents"
    );
    // A database of no library is missing to a reader, and is not created by one.
    let empty = TestDatabase::new(&admin);
    let err = Library::open(&empty.location(), OpenMode::Existing).expect_err("missing");
    assert!(matches!(err, LibraryError::Missing { .. }), "{err}");
}

#[test]
fn sqlite_to_postgresql_to_sqlite_is_byte_identical() {
    let Some(admin) = server() else { return };
    let db = TestDatabase::new(&admin);
    let dir = tempfile::tempdir().expect("temp dir");
    let mut first = filled_at(&Location::File(dir.path().join("first.sqlite")));
    first
        .record_validation("abc", &serde_json::json!({"population": {"x": 1}}))
        .expect("validate");
    first
        .remove_session(&sheet(4, 1).session_sha256)
        .expect("remove");
    let mut pg = Library::open(&db.location(), OpenMode::Add).expect("create");
    let there = migrate(&first, &mut pg).expect("to PostgreSQL");
    let mut back = Library::open(
        &Location::File(dir.path().join("back.sqlite")),
        OpenMode::Add,
    )
    .expect("create");
    let again = migrate(&pg, &mut back).expect("back to SQLite");
    assert_eq!(export_bytes(&back), export_bytes(&first));
    assert_eq!(export_bytes(&pg), export_bytes(&first));
    assert_eq!(there.export_sha256, again.export_sha256);
    assert_eq!((there.sessions, there.validations), (3, 1));
    assert_eq!(
        back.validation_record("abc").expect("read"),
        first.validation_record("abc").expect("read")
    );
    // The trail came along: the new library's making, PostgreSQL's making, every entry of
    // the first (copied twice: its origin's origin is the original), PostgreSQL's
    // migration, then this one.
    let trail = back.audit_entries().expect("history");
    let originals = first.audit_entries().expect("history");
    let actions: Vec<&str> = trail.iter().map(|e| e.action.as_str()).collect();
    assert_eq!(trail.len(), originals.len() + 4, "{actions:?}");
    assert_eq!(actions[..2], ["create", "create"]);
    assert_eq!(actions[actions.len() - 2..], ["migrate", "migrate"]);
    for (copy, original) in trail[2..].iter().zip(&originals) {
        assert_eq!(copy.action, original.action);
        assert_eq!(copy.detail["origin"]["origin"]["entry"], original.entry);
        assert_eq!(copy.detail["origin"]["origin"]["at"], original.at.as_str());
    }
    // A migration goes into an empty library only.
    let err = migrate(&first, &mut back).expect_err("not empty");
    assert!(err.to_string().contains("not empty"), "{err}");
}

#[test]
fn roles_are_enforced_by_the_database_and_the_trail_cannot_be_changed() {
    let Some(admin) = server() else { return };
    let db = TestDatabase::new(&admin);
    drop(filled_at(&db.location()));
    let examiner = Location::Postgres(db.login(Some(EXAMINER_ROLE)));
    let curator = Location::Postgres(db.login(Some(CURATOR_ROLE)));
    let nobody = Location::Postgres(db.login(None));
    // An examiner reads, searches (caching the population) but cannot change a stock.
    let mut library = Library::open(&examiner, OpenMode::Existing).expect("an examiner opens");
    assert_eq!(library.sheet_count().expect("count"), 4);
    library
        .cache_population("abc", &serde_json::json!({"population": 1}))
        .expect("an examiner caches a population");
    for (what, err) in [
        (
            "add",
            library
                .add_sheets(&stock("PPC"), &[sheet(9, 1)])
                .expect_err("add"),
        ),
        ("remove", library.remove_stock("PPC").expect_err("remove")),
        (
            "validate",
            library
                .record_validation("abc", &serde_json::json!({}))
                .expect_err("validate"),
        ),
    ] {
        assert!(matches!(err, LibraryError::Denied { .. }), "{what}: {err}");
        let text = err.to_string();
        assert!(
            text.contains(CURATOR_ROLE) && text.contains("refused"),
            "{what}: {text}"
        );
    }
    assert_eq!(library.sheet_count().expect("count"), 4, "nothing changed");
    // A curator adds and removes, and the trail names the curator's login.
    let mut library = Library::open(&curator, OpenMode::Existing).expect("a curator opens");
    library
        .add_sheets(&stock("PPC"), &[sheet(9, 1)])
        .expect("a curator adds");
    library
        .remove_session(&sheet(9, 1).session_sha256)
        .expect("a curator removes");
    let trail = library.audit_entries().expect("history");
    let login = match &curator {
        Location::Postgres(url) => url
            .split("://")
            .nth(1)
            .and_then(|r| r.split('@').next())
            .expect("user")
            .to_string(),
        Location::File(_) => unreachable!(),
    };
    assert_eq!(
        trail[trail.len() - 2].db_user.as_deref(),
        Some(login.as_str())
    );
    // A login of neither role cannot even read it.
    let err = Library::open(&nobody, OpenMode::Existing).expect_err("no role");
    assert!(matches!(err, LibraryError::Denied { .. }), "{err}");
    // Nobody changes the trail, not even its owner.
    for url in [
        db.admin_url(),
        match &curator {
            Location::Postgres(u) => u.clone(),
            _ => unreachable!(),
        },
    ] {
        let mut client = ::postgres::Client::connect(&url, NoTls).expect("connect");
        for sql in [
            "UPDATE gonio.audit SET action = 'add' WHERE entry = 1",
            "DELETE FROM gonio.audit WHERE entry = 1",
            "TRUNCATE gonio.audit",
        ] {
            let err = client.batch_execute(sql).expect_err(sql);
            let db_error = err.as_db_error().expect("the server refused");
            assert!(
                db_error.message().contains("append-only")
                    || db_error.message().contains("permission denied"),
                "{sql}: {db_error:?}"
            );
        }
    }
}

#[test]
fn a_foreign_or_newer_database_is_refused_and_left_as_it_is() {
    let Some(admin) = server() else { return };
    let sql = |db: &TestDatabase, sql: &str| {
        ::postgres::Client::connect(&db.admin_url(), NoTls)
            .expect("connect")
            .batch_execute(sql)
            .expect(sql);
    };
    // Another program's schema of the same name.
    let foreign = TestDatabase::new(&admin);
    sql(
        &foreign,
        "CREATE SCHEMA gonio; CREATE TABLE gonio.things (x int)",
    );
    for mode in [OpenMode::Existing, OpenMode::Add] {
        let err = Library::open(&foreign.location(), mode).expect_err("foreign");
        assert!(matches!(err, LibraryError::Foreign { .. }), "{err}");
    }
    // A library whose table was changed by other means.
    let changed = TestDatabase::new(&admin);
    drop(filled_at(&changed.location()));
    sql(
        &changed,
        "ALTER TABLE gonio.sheets ALTER COLUMN lot TYPE integer USING 0",
    );
    let err = Library::open(&changed.location(), OpenMode::Existing).expect_err("changed");
    assert!(
        err.to_string().contains("gonio.sheets.lot is integer"),
        "{err}"
    );
    // A newer gonio's library.
    let newer = TestDatabase::new(&admin);
    drop(filled_at(&newer.location()));
    sql(
        &newer,
        "UPDATE gonio.meta SET value = '4' WHERE key = 'schema_version'",
    );
    let before = export_count(&newer);
    for mode in [OpenMode::Existing, OpenMode::Add] {
        let err = Library::open(&newer.location(), mode).expect_err("newer");
        assert!(matches!(err, LibraryError::Newer { found: 4, .. }), "{err}");
        assert!(err.to_string().contains("update gonio"), "{err}");
    }
    assert_eq!(export_count(&newer), before, "left as it is");
}

/// Rows of the library's tables and trail, read directly.
fn export_count(db: &TestDatabase) -> (i64, i64, i64) {
    let row = ::postgres::Client::connect(&db.admin_url(), NoTls)
        .expect("connect")
        .query_one(
            "SELECT (SELECT count(*) FROM gonio.sheets), (SELECT count(*) FROM gonio.spots), (SELECT count(*) FROM gonio.audit)",
            &[],
        )
        .expect("count");
    (row.get(0), row.get(1), row.get(2))
}
