//! `gonio library` on the PostgreSQL server CI starts (`.ci/postgres`, named by
//! `GONIO_TEST_POSTGRES`; without it a NOTICE and nothing run, unless
//! `GONIO_REQUIRE_POSTGRES=1`): an examiner's import refused by the database with the
//! reason, a curator's taken and in the trail under the curator's login, the library named
//! once in the settings file, and SQLite → PostgreSQL → SQLite by `gonio library migrate`
//! with exports byte-identical.
use crate::cli_support::{stderr, temp_dir};
use host::study::library_scale::{Shape, write_library};
use std::process::{Command, Output, Stdio};

fn server() -> Option<String> {
    match std::env::var("GONIO_TEST_POSTGRES") {
        Ok(url) if !url.is_empty() => Some(url),
        _ => {
            assert!(
                std::env::var("GONIO_REQUIRE_POSTGRES").as_deref() != Ok("1"),
                "GONIO_REQUIRE_POSTGRES=1 but GONIO_TEST_POSTGRES names no server"
            );
            eprintln!("NOTICE: no PostgreSQL server (GONIO_TEST_POSTGRES unset): left out");
            None
        }
    }
}

/// `admin` with its user and database replaced.
fn url_of(admin: &str, user: &str, database: &str) -> String {
    let (scheme, rest) = admin.split_once("://").expect("a URL");
    let (authority, tail) = rest.split_at(rest.find('/').expect("a database"));
    let host = authority.rsplit_once('@').map_or(authority, |(_, h)| h);
    let query = tail
        .split_once('?')
        .map(|(_, q)| format!("?{q}"))
        .unwrap_or_default();
    format!("{scheme}://{user}@{host}/{database}{query}")
}

fn gonio_in(settings: &std::path::Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_gonio"))
        .args(args)
        .env("GONIO_SETTINGS", settings)
        .stdin(Stdio::null())
        .output()
        .expect("run gonio")
}

#[test]
fn examiners_search_curators_add_and_a_library_migrates_both_ways() {
    let Some(admin) = server() else { return };
    let name = format!("gonio_cli_{}", std::process::id());
    let mut client = postgres::Client::connect(&admin, postgres::NoTls).expect("server");
    for sql in [
        format!("DROP DATABASE IF EXISTS {name} WITH (FORCE)"),
        format!("CREATE DATABASE {name} ENCODING 'UTF8' TEMPLATE template0"),
    ] {
        client.batch_execute(&sql).expect("a database");
    }
    let dir = temp_dir("library-postgres", "cli");
    std::fs::create_dir_all(&dir).expect("dir");
    let exchange = dir.join("stocks.jsonl");
    let shape = Shape {
        stocks: 6,
        sheets: 2,
        spots: 2,
        seed: 29,
    };
    write_library(&shape, &mut std::fs::File::create(&exchange).expect("file")).expect("write");
    let file = dir.join("first.sqlite");
    let (lib, ex) = (file.to_str().unwrap(), exchange.to_str().unwrap());
    let settings = dir.join("settings.toml");
    std::fs::write(&settings, "").expect("settings");
    let out = gonio_in(&settings, &["library", "--library", lib, "import", ex]);
    assert!(out.status.success(), "{}", stderr(&out));
    // The owner makes the library (schema and roles) by migrating the file into it.
    let owner = url_of(&admin, "postgres", &name);
    let out = gonio_in(
        &settings,
        &["library", "--library", lib, "migrate", "--to", &owner],
    );
    assert!(out.status.success(), "{}", stderr(&out));
    let stamp = std::process::id();
    for (user, role) in [("examiner", "gonio_examiner"), ("curator", "gonio_curator")] {
        client
            .batch_execute(&format!(
                "DROP ROLE IF EXISTS {user}_{stamp}; CREATE ROLE {user}_{stamp} LOGIN IN ROLE {role}"
            ))
            .expect("a login");
    }
    let examiner = url_of(&admin, &format!("examiner_{stamp}"), &name);
    let curator = url_of(&admin, &format!("curator_{stamp}"), &name);
    // The institute names its library once: the examiner's settings.
    std::fs::write(&settings, format!("[library]\nlocation = \"{examiner}\"\n")).expect("settings");
    let out = gonio_in(&settings, &["library", "list"]);
    assert!(out.status.success(), "{}", stderr(&out));
    assert!(String::from_utf8_lossy(&out.stdout).contains("6 stocks"));
    // An examiner cannot add: the database refuses, gonio says who may.
    let more = dir.join("more.jsonl");
    // The same six stocks and two more: the six are skipped, the two new.
    let shape = Shape {
        stocks: 8,
        sheets: 2,
        spots: 2,
        seed: 29,
    };
    write_library(&shape, &mut std::fs::File::create(&more).expect("file")).expect("write");
    let out = gonio_in(&settings, &["library", "import", more.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    let said = stderr(&out);
    assert!(
        said.contains("refused")
            && said.contains("gonio_curator")
            && said.contains(&format!("examiner_{stamp}")),
        "{said}"
    );
    // A curator can; the trail names the curator.
    let out = gonio_in(
        &settings,
        &[
            "library",
            "--library",
            &curator,
            "import",
            more.to_str().unwrap(),
        ],
    );
    assert!(out.status.success(), "{}", stderr(&out));
    let out = gonio_in(&settings, &["library", "history"]);
    let shown = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success()
            && shown.contains(&format!("curator_{stamp}"))
            && shown.contains("import"),
        "{shown}"
    );
    // And back to a file: the same export as the first, byte for byte.
    let back = dir.join("back.sqlite");
    let out = gonio_in(
        &settings,
        &[
            "library",
            "--library",
            &owner,
            "migrate",
            "--to",
            back.to_str().unwrap(),
        ],
    );
    assert!(out.status.success(), "{}", stderr(&out));
    let export = |from: &str, to: &std::path::Path| {
        let out = gonio_in(
            &settings,
            &["library", "--library", from, "export", to.to_str().unwrap()],
        );
        assert!(out.status.success(), "{}", stderr(&out));
        std::fs::read(to).expect("export")
    };
    let (a, b) = (
        export(&owner, &dir.join("a.jsonl")),
        export(back.to_str().unwrap(), &dir.join("b.jsonl")),
    );
    assert_eq!(a, b, "PostgreSQL and its copy export the same bytes");
    // A URL's password is never printed.
    let secret = url_of(&admin, "nobody:hunter2", &name);
    let out = gonio_in(&settings, &["library", "--library", &secret, "list"]);
    assert!(!out.status.success());
    assert!(
        !stderr(&out).contains("hunter2") && stderr(&out).contains("***"),
        "{}",
        stderr(&out)
    );
    drop(client);
    let mut client = postgres::Client::connect(&admin, postgres::NoTls).expect("server");
    for sql in [
        format!("DROP DATABASE IF EXISTS {name} WITH (FORCE)"),
        format!("DROP ROLE IF EXISTS examiner_{stamp}"),
        format!("DROP ROLE IF EXISTS curator_{stamp}"),
    ] {
        let _ = client.batch_execute(&sql);
    }
    let _ = std::fs::remove_dir_all(&dir);
}
