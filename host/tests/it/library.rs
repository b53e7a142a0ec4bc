//! `gonio library` end to end, as a user would run it: sheets measured on the simulator,
//! added under stocks, listed, exported and imported, searched and removed.
use crate::cli_support;
use cli_support::{gonio, stderr, temp_dir};
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

/// Measure `sample` on the simulator into `parent/name`, with `seed`.
fn measure(parent: &Path, name: &str, sample: &str, seed: u64) -> PathBuf {
    let dir = parent.join(name);
    let out = gonio(&[
        "measure",
        "--spots",
        "1",
        "--sim",
        sample,
        "--out",
        s(&dir),
        "--seed",
        &seed.to_string(),
    ]);
    assert!(
        out.status.success(),
        "measure {sample} seed {seed}: {}",
        stderr(&out)
    );
    dir
}

fn s(path: &Path) -> &str {
    path.to_str().expect("a UTF-8 temp path")
}

fn stdout(out: &Output) -> String {
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn json(out: &Output) -> serde_json::Value {
    assert!(out.status.success(), "{}", stderr(out));
    serde_json::from_str(&stdout(out)).expect("one JSON object")
}

fn code(out: &Output) -> i32 {
    out.status.code().expect("exited")
}

/// (stock, sheets, spots) of every stock, by `list --json`.
fn listed(library: &Path) -> Vec<(String, u64, u64)> {
    let list = json(&gonio(&[
        "library",
        "list",
        "--json",
        "--library",
        s(library),
    ]));
    list["stocks"]
        .as_array()
        .expect("stocks")
        .iter()
        .map(|x| {
            (
                x["name"].as_str().expect("name").to_string(),
                x["sheets"].as_u64().expect("n"),
                x["spots"].as_u64().expect("n"),
            )
        })
        .collect()
}

#[test]
fn add_list_export_import_and_remove_measured_sheets() {
    let root = temp_dir("library", "e2e");
    let library = root.join("lib").join("library.sqlite");
    let ppc1 = measure(&root, "ppc1", "PPC", 1);
    let ppc2 = measure(&root, "ppc2", "PPC", 2);
    let g = measure(&root, "g", "G", 3);

    // Reading a library that does not exist says so, and creates nothing.
    let out = gonio(&["library", "list", "--library", s(&library)]);
    assert_eq!(code(&out), 1);
    assert!(
        stderr(&out).contains("no library here yet"),
        "{}",
        stderr(&out)
    );
    assert!(!library.exists());

    let out = gonio(&[
        "library",
        "add",
        "--library",
        s(&library),
        "--stock",
        "PPC",
        "--lot",
        "ream 7",
        "--manufacturer",
        "Acme",
        s(&ppc1),
        s(&ppc2),
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    assert!(stdout(&out).contains("2 sheets added"), "{}", stdout(&out));
    // --library after the subcommand or before it.
    let out = gonio(&[
        "library",
        "--library",
        s(&library),
        "add",
        "--stock",
        "G",
        s(&g),
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    assert_eq!(
        listed(&library),
        vec![("G".into(), 1, 1), ("PPC".into(), 2, 2)]
    );

    // The same session again, under any stock: refused, naming the stock it is under.
    let out = gonio(&[
        "library",
        "add",
        "--library",
        s(&library),
        "--stock",
        "Other",
        s(&ppc2),
    ]);
    assert_eq!(code(&out), 1);
    assert!(
        stderr(&out).contains("already in the library under stock 'PPC'"),
        "{}",
        stderr(&out)
    );
    assert_eq!(listed(&library).len(), 2);

    // Export, import into an empty library, export again: the same bytes.
    let exported = root.join("library.jsonl");
    let out = gonio(&["library", "export", "--library", s(&library), s(&exported)]);
    assert!(out.status.success(), "{}", stderr(&out));
    let first = std::fs::read_to_string(&exported).expect("export written");
    assert_eq!(first.lines().count(), 3);
    let record: serde_json::Value =
        serde_json::from_str(first.lines().next().expect("a line")).expect("JSON");
    assert_eq!(record["schema"], host::schema::LIBRARY_RECORD);
    assert_eq!(record["stock"], "G");
    assert_eq!(
        record["instrument_serial"].as_str().map(|x| x.is_empty()),
        Some(false)
    );
    let copy = root.join("copy.sqlite");
    let out = gonio(&["library", "import", "--library", s(&copy), s(&exported)]);
    assert!(out.status.success(), "{}", stderr(&out));
    assert!(
        stdout(&out).contains("3 sessions added, 0 already present"),
        "{}",
        stdout(&out)
    );
    let again = root.join("again.jsonl");
    assert!(
        gonio(&["library", "export", "--library", s(&copy), s(&again)])
            .status
            .success()
    );
    assert_eq!(
        std::fs::read_to_string(&again).expect("export written"),
        first
    );
    // Importing it again skips every session.
    let out = gonio(&["library", "import", "--library", s(&copy), s(&exported)]);
    assert!(
        stdout(&out).contains("0 sessions added, 3 already present"),
        "{}",
        stdout(&out)
    );

    // A bad exchange file is refused at its line, and creates no library.
    let bad = root.join("bad.jsonl");
    std::fs::write(
        &bad,
        format!(
            "{}not a record\n",
            first
                .lines()
                .next()
                .map(|l| format!("{l}\n"))
                .unwrap_or_default()
        ),
    )
    .expect("write");
    let fresh = root.join("fresh.sqlite");
    let out = gonio(&["library", "import", "--library", s(&fresh), s(&bad)]);
    assert_eq!(code(&out), 1);
    assert!(
        stderr(&out).contains(&format!("{}:2:", bad.display())),
        "{}",
        stderr(&out)
    );
    assert!(!fresh.exists());

    // Remove one session by a prefix of its SHA-256 (that of its MANIFEST.sha256), then a stock.
    let manifest = std::fs::read(ppc1.join("MANIFEST.sha256")).expect("manifest");
    let sha = host::output::folder::manifest::sha256_hex(&manifest);
    assert!(
        first.contains(&sha),
        "the identity is the manifest's SHA-256"
    );
    let out = gonio(&[
        "library",
        "remove",
        "--library",
        s(&library),
        "--session",
        &sha[..12],
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    assert_eq!(
        listed(&library),
        vec![("G".into(), 1, 1), ("PPC".into(), 1, 1)]
    );
    let out = gonio(&[
        "library",
        "remove",
        "--library",
        s(&library),
        "--stock",
        "G",
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    assert_eq!(listed(&library), vec![("PPC".into(), 1, 1)]);
    let out = gonio(&[
        "library",
        "remove",
        "--library",
        s(&library),
        "--stock",
        "G",
    ]);
    assert_eq!(code(&out), 1);
    assert!(stderr(&out).contains("no stock 'G'"), "{}", stderr(&out));
    // Neither --stock nor --session: a usage error.
    assert_eq!(
        code(&gonio(&["library", "remove", "--library", s(&library)])),
        2
    );
    let _ = std::fs::remove_dir_all(&root);
}

#[test]
fn search_ranks_the_stock_of_the_sheet_first() {
    let root = temp_dir("library", "search");
    let library = root.join("library.sqlite");
    // Four stocks: the fewest a population is estimated from.
    for (stock, seeds) in [
        ("PPC", [11u64, 12]),
        ("G", [13, 14]),
        ("MC", [15, 16]),
        ("J1", [17, 18]),
    ] {
        let dirs: Vec<PathBuf> = seeds
            .iter()
            .map(|&seed| measure(&root, &format!("{stock}-{seed}"), stock, seed))
            .collect();
        let mut args = vec!["library", "add", "--library", s(&library), "--stock", stock];
        args.extend(dirs.iter().map(|d| s(d)));
        let out = gonio(&args);
        assert!(out.status.success(), "{}", stderr(&out));
    }
    for (sample, seed) in [("PPC", 21u64), ("G", 22), ("MC", 23)] {
        let sheet = measure(&root, &format!("query-{sample}"), sample, seed);
        let out = gonio(&[
            "library",
            "search",
            "--library",
            s(&library),
            "--json",
            "--top",
            "2",
            s(&sheet),
        ]);
        // Four stocks of two sheets: too few same-stock pairs to validate the population,
        // which is said (exit 3).
        assert_eq!(code(&out), 3, "{}", stderr(&out));
        let found: serde_json::Value = serde_json::from_str(&stdout(&out)).expect("JSON");
        assert!(
            found["warnings"]
                .as_array()
                .is_some_and(|w| w.iter().any(|w| w["kind"] == "not-validated")),
            "{found}"
        );
        assert!(
            found["caveat"]
                .as_str()
                .is_some_and(|c| c.contains("not an identification")),
            "{found}"
        );
        let ranking = found["ranking"].as_array().expect("ranking");
        assert_eq!(ranking.len(), 2, "{found}");
        assert_eq!(ranking[0]["stock"], sample, "{found}");
        assert!(
            ranking[0]["log10_lr"].as_f64() > ranking[1]["log10_lr"].as_f64(),
            "{found}"
        );
        assert_eq!(found["stocks"], 4);
    }
    // A sheet in the library is left out of its own stock: it still ranks its stock first.
    let out = gonio(&[
        "library",
        "search",
        "--library",
        s(&library),
        "--json",
        s(&root.join("PPC-11")),
    ]);
    assert_eq!(code(&out), 3, "{}", stderr(&out));
    let found: serde_json::Value = serde_json::from_str(&stdout(&out)).expect("JSON");
    assert_eq!(found["ranking"][0]["stock"], "PPC", "{found}");
    assert_eq!(found["ranking"][0]["sheets"], 1, "{found}");
    assert!(found["excluded_own_session"].is_string(), "{found}");
    let out = gonio(&[
        "library",
        "search",
        "--library",
        s(&library),
        s(&root.join("query-G")),
    ]);
    assert_eq!(code(&out), 3, "{}", stderr(&out));
    assert!(
        stdout(&out)
            .lines()
            .nth(3)
            .is_some_and(|l| l.contains(" G ")),
        "{}",
        stdout(&out)
    );
    let _ = std::fs::remove_dir_all(&root);
}

#[test]
fn two_processes_adding_at_once_both_succeed() {
    let root = temp_dir("library", "concurrent");
    let sheets: Vec<PathBuf> = (0..6u64)
        .map(|k| {
            measure(
                &root,
                &format!("s{k}"),
                if k % 2 == 0 { "PPC" } else { "G" },
                40 + k,
            )
        })
        .collect();
    // Each round a new library file: both processes race to create it, then to write.
    for round in 0..3 {
        let library = root.join(format!("library-{round}.sqlite"));
        let children: Vec<_> = [&sheets[2 * round], &sheets[2 * round + 1]]
            .iter()
            .enumerate()
            .map(|(k, dir)| {
                Command::new(env!("CARGO_BIN_EXE_gonio"))
                    .args([
                        "library",
                        "add",
                        "--library",
                        s(&library),
                        "--stock",
                        &format!("stock {k}"),
                        s(dir),
                    ])
                    .stdin(Stdio::null())
                    .stdout(Stdio::piped())
                    .stderr(Stdio::piped())
                    .spawn()
                    .expect("spawn gonio")
            })
            .collect();
        for child in children {
            let out = child.wait_with_output().expect("wait");
            assert!(out.status.success(), "round {round}: {}", stderr(&out));
        }
        assert_eq!(
            listed(&library),
            vec![("stock 0".into(), 1, 1), ("stock 1".into(), 1, 1)],
            "round {round}"
        );
    }
    let _ = std::fs::remove_dir_all(&root);
}

#[test]
fn a_changed_or_flagged_session_is_not_added() {
    let root = temp_dir("library", "refused");
    let library = root.join("library.sqlite");
    let changed = measure(&root, "changed", "PPC", 31);
    std::fs::write(changed.join("notes.txt"), "added after the session\n").expect("write");
    let out = gonio(&[
        "library",
        "add",
        "--library",
        s(&library),
        "--stock",
        "PPC",
        s(&changed),
    ]);
    assert_eq!(code(&out), 1);
    assert!(stderr(&out).contains("does not verify"), "{}", stderr(&out));
    assert!(!library.exists(), "a refused add leaves no library behind");

    // A flagged result: `ok` made false, the manifest rewritten, its signature (which no
    // longer holds) removed and the report drawn again, so the folder verifies (unsigned).
    let flagged = measure(&root, "flagged", "PPC", 32);
    let file = flagged.join("session.json");
    let mut doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&file).expect("read")).expect("JSON");
    doc["ok"] = serde_json::Value::Bool(false);
    std::fs::write(&file, serde_json::to_string_pretty(&doc).expect("JSON")).expect("write");
    std::fs::write(
        flagged.join("MANIFEST.sha256"),
        host::output::folder::manifest::manifest_text(&flagged).expect("manifest"),
    )
    .expect("write");
    let _ = std::fs::remove_file(flagged.join("signature.json"));
    assert!(
        gonio(&["report", s(&flagged)]).status.success(),
        "the report drawn from the changed files"
    );
    let out = gonio(&[
        "library",
        "add",
        "--library",
        s(&library),
        "--stock",
        "PPC",
        s(&flagged),
    ]);
    assert_eq!(code(&out), 1);
    assert!(
        stderr(&out).contains("flagged") && stderr(&out).contains("--allow-flagged"),
        "{}",
        stderr(&out)
    );
    let out = gonio(&[
        "library",
        "add",
        "--library",
        s(&library),
        "--stock",
        "PPC",
        "--allow-flagged",
        s(&flagged),
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    assert_eq!(listed(&library), vec![("PPC".into(), 1, 1)]);
    let _ = std::fs::remove_dir_all(&root);
}

#[test]
fn a_file_that_is_not_a_library_is_reported_and_left_alone() {
    let root = temp_dir("library", "not-a-library");
    std::fs::create_dir_all(&root).expect("mkdir");
    let library = root.join("library.sqlite");
    let bytes = b"these are someone's notes, not a database\n".repeat(100);
    std::fs::write(&library, &bytes).expect("write");
    let sheet = measure(&root, "s", "PPC", 33);
    for args in [
        vec!["library", "list"],
        vec!["library", "add", "--stock", "PPC", s(&sheet)],
        vec!["library", "search", s(&sheet)],
    ] {
        let mut args = args.clone();
        args.extend(["--library", s(&library)]);
        let out = gonio(&args);
        assert_eq!(code(&out), 1, "{args:?}");
        assert!(
            stderr(&out).contains(&format!("{}: not a gonio library", library.display())),
            "{args:?}: {}",
            stderr(&out)
        );
        assert_eq!(std::fs::read(&library).expect("read"), bytes, "{args:?}");
    }
    let _ = std::fs::remove_dir_all(&root);
}

#[test]
fn the_default_library_is_under_xdg_data_home() {
    let root = temp_dir("library", "xdg");
    let sheet = measure(&root, "s", "G", 34);
    let data_home = root.join("data");
    let out = Command::new(env!("CARGO_BIN_EXE_gonio"))
        .args(["library", "add", "--stock", "G", s(&sheet)])
        .env("XDG_DATA_HOME", &data_home)
        .stdin(Stdio::null())
        .output()
        .expect("run gonio");
    assert!(out.status.success(), "{}", stderr(&out));
    assert!(data_home.join("gonio").join("library.sqlite").is_file());
    let _ = std::fs::remove_dir_all(&root);
}

/// A real exchange record (a G sheet's spot, as `docs/LIBRARY.md` shows it) for `stock`
/// and session number `n`, with `edit` applied to it.
fn record(stock: &str, n: u64, edit: impl FnOnce(&mut serde_json::Value)) -> String {
    let mut r = serde_json::json!({
        "schema": host::schema::LIBRARY_RECORD, "stock": stock, "manufacturer": null,
        "stock_notes": null, "session_sha256": format!("{n:064x}"), "sample": "G", "lot": null,
        "measured_at": "2026-12-02T04:41:50.753+00:00", "instrument_serial": "SIM-0001",
        "session_path": "s3", "added_at": "2026-12-02T04:41:51.388Z", "spot": 0, "spots": 1,
        "sigma_deg": 0.79989953098683, "rho_s": 58.2277779149291, "rho_d": 0.855095714173521,
        "covariance": [
            [2.884551372313763e-7, -0.00017563109108595376, -1.0147899589337306e-8],
            [-0.00017563109108595376, 0.2797897003969915, 0.0012528422184519307],
            [-1.0147899589337306e-8, 0.0012528422184519307, 0.000018736031808713217]
        ]
    });
    edit(&mut r);
    format!("{r}\n")
}

/// Issue 30 (D6): a record that is not a possible measurement is refused at its line with
/// the reason, and nothing of its file is stored, however good the lines before it.
#[test]
fn import_refuses_impossible_records_and_stores_nothing_of_their_file() {
    let root = temp_dir("library", "impossible");
    std::fs::create_dir_all(&root).expect("temp dir");
    let library = root.join("library.sqlite");
    let good = root.join("good.jsonl");
    std::fs::write(&good, record("S1", 1, |_| {})).expect("write");
    let out = gonio(&["library", "import", "--library", s(&library), s(&good)]);
    assert!(out.status.success(), "{}", stderr(&out));
    let before = std::fs::read(&library).expect("library");
    let cov =
        |c: [[f64; 3]; 3]| move |r: &mut serde_json::Value| r["covariance"] = serde_json::json!(c);
    let cases: Vec<(&str, String)> = vec![
        (
            "negative-definite",
            record(
                "S9",
                9,
                cov([[-1e-6, 0.0, 0.0], [0.0, -0.3, 0.0], [0.0, 0.0, -2e-5]]),
            ),
        ),
        (
            "covariance of 1e308",
            record(
                "S9",
                9,
                cov([[1e308, 0.0, 0.0], [0.0, 1e308, 0.0], [0.0, 0.0, 1e308]]),
            ),
        ),
        ("zero covariance", record("S9", 9, cov([[0.0; 3]; 3]))),
        (
            "σ of 1e308",
            record("S9", 9, |r| r["sigma_deg"] = serde_json::json!(1e308)),
        ),
        (
            "negative ρd",
            record("S9", 9, |r| r["rho_d"] = serde_json::json!(-0.5)),
        ),
        (
            "asymmetric",
            record(
                "S9",
                9,
                cov([[2.9e-7, 1e-4, 0.0], [-1e-4, 0.28, 0.0], [0.0, 0.0, 1.9e-5]]),
            ),
        ),
        (
            "correlation of 1",
            record(
                "S9",
                9,
                cov([[1e-6, 1e-3, 0.0], [1e-3, 1.0, 0.0], [0.0, 0.0, 1.9e-5]]),
            ),
        ),
        (
            "sd 1e-12 of the value",
            record(
                "S9",
                9,
                cov([[1e-24, 0.0, 0.0], [0.0, 0.28, 0.0], [0.0, 0.0, 1.9e-5]]),
            ),
        ),
    ];
    let reasons = [
        "not positive definite",
        "implausible for the instrument",
        "not positive definite",
        "outside the fit's range",
        "outside the fit's range",
        "not symmetric",
        "not positive definite",
        "implausible for the instrument",
    ];
    for ((what, bad), reason) in cases.iter().zip(reasons) {
        let file = root.join("bad.jsonl");
        // A good record of a new stock first: it must not be stored either.
        std::fs::write(&file, format!("{}{bad}", record("S2", 2, |_| {}))).expect("write");
        let out = gonio(&["library", "import", "--library", s(&library), s(&file)]);
        let err = stderr(&out);
        assert_eq!(code(&out), 1, "{what}: {err}");
        assert!(
            err.contains(&format!("{}:2:", file.display())) && err.contains(reason),
            "{what}: {err}"
        );
        assert!(err.contains("nothing was imported"), "{what}: {err}");
        assert_eq!(listed(&library), vec![("S1".into(), 1, 1)], "{what}");
    }
    // A refused import does not write to the file at all.
    assert_eq!(std::fs::read(&library).expect("library"), before);
    let _ = std::fs::remove_dir_all(&root);
}

/// Issue 30 (D5): a stock name of 120,000 characters is listed and searched, cut short
/// with an ellipsis, without a panic.
#[test]
fn a_very_long_stock_name_is_listed_and_searched_cut_short() {
    let root = temp_dir("library", "long-name");
    let library = root.join("library.sqlite");
    let long = "L".repeat(120_000);
    for (stock, sample, seed) in [
        ("PPC", "PPC", 41u64),
        ("PPC", "PPC", 42),
        ("G", "G", 43),
        ("MC", "MC", 44),
        (long.as_str(), "J1", 45),
    ] {
        let dir = measure(&root, &format!("{sample}-{seed}"), sample, seed);
        let out = gonio(&[
            "library",
            "add",
            "--library",
            s(&library),
            "--stock",
            stock,
            s(&dir),
        ]);
        assert!(out.status.success(), "{}", stderr(&out));
    }
    let out = gonio(&["library", "list", "--library", s(&library)]);
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    let text = stdout(&out);
    assert!(text.contains(&format!("{}…", "L".repeat(40))), "{text}");
    assert!(text.lines().all(|l| l.chars().count() < 200), "{text}");
    let query = measure(&root, "query", "G", 46);
    let out = gonio(&["library", "search", "--library", s(&library), s(&query)]);
    assert!(matches!(code(&out), 0 | 3), "{}", stderr(&out));
    let text = stdout(&out);
    assert!(text.contains(&format!("{}…", "L".repeat(40))), "{text}");
    let _ = std::fs::remove_dir_all(&root);
}

/// Issue 31: a spot folder of a sheet already in the library (or the sheet of a spot
/// already in it) is the same sheet again: refused, whichever comes first, and within one
/// add.
#[test]
fn a_sheet_and_its_own_spot_are_one_sheet_counted_once() {
    let root = temp_dir("library", "same-sheet");
    let sheet = root.join("G-a");
    let out = gonio(&[
        "measure",
        "--spots",
        "2",
        "--sim",
        "G",
        "--seed",
        "33",
        "--out",
        s(&sheet),
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    let spot = sheet.join("spot-1");
    let add = |library: &Path, dirs: &[&Path]| {
        let mut args = vec![
            "library",
            "add",
            "--library",
            s(library),
            "--stock",
            "Stock-G",
        ];
        args.extend(dirs.iter().map(|d| s(d)));
        gonio(&args)
    };
    // The sheet first, then its spot.
    let library = root.join("sheet-first.sqlite");
    assert!(add(&library, &[&sheet]).status.success());
    let out = add(&library, &[&spot]);
    assert_eq!(code(&out), 1, "{}", stdout(&out));
    assert!(
        stderr(&out).contains("same sheet") && stderr(&out).contains("Stock-G"),
        "{}",
        stderr(&out)
    );
    assert_eq!(listed(&library), vec![("Stock-G".into(), 1, 2)]);
    // The spot first, then its sheet.
    let library = root.join("spot-first.sqlite");
    assert!(add(&library, &[&spot]).status.success());
    let out = add(&library, &[&sheet]);
    assert_eq!(code(&out), 1, "{}", stdout(&out));
    assert!(stderr(&out).contains("same sheet"), "{}", stderr(&out));
    assert_eq!(listed(&library), vec![("Stock-G".into(), 1, 1)]);
    // Both in one add: nothing added.
    let library = root.join("together.sqlite");
    let out = add(&library, &[&sheet, &spot]);
    assert_eq!(code(&out), 1, "{}", stdout(&out));
    assert!(stderr(&out).contains("same sheet"), "{}", stderr(&out));
    assert!(!library.exists(), "a refused add leaves no library behind");
    let _ = std::fs::remove_dir_all(&root);
}

/// Issue 29's search at scale, small (correctness, not time): a synthetic library drawn
/// anew on every run is imported; its export is the generator's file byte for byte (export
/// streams record by record); the first search makes the population and caches it in the
/// library, the second reads it from the cache, and both rank the stocks with the same
/// ratios as the evidence module computes in process from the library's sheets; a sheet
/// added changes the contents, and the next search is made afresh for them.
#[test]
fn a_search_is_the_same_made_afresh_or_from_the_cache_and_follows_the_library() {
    use host::analysis::evidence::{self, validation};
    use host::output::library::{Library, OpenMode};
    use host::study::library_scale::{Shape, write_library, write_questioned};
    let seed = crate::common::run_seed();
    let root = temp_dir("library", "scale");
    std::fs::create_dir_all(&root).expect("temp dir");
    let shape = Shape {
        stocks: 30,
        sheets: 3,
        spots: 3,
        seed,
    };
    let exchange = root.join("library.jsonl");
    let mut file = std::fs::File::create(&exchange).expect("exchange file");
    assert_eq!(write_library(&shape, &mut file).expect("write"), 30 * 3 * 3);
    drop(file);
    let library = root.join("library.sqlite");
    let out = gonio(&["library", "--library", s(&library), "import", s(&exchange)]);
    assert!(out.status.success(), "seed {seed}: {}", stderr(&out));
    let exported = root.join("export.jsonl");
    let out = gonio(&["library", "--library", s(&library), "export", s(&exported)]);
    assert!(out.status.success(), "seed {seed}: {}", stderr(&out));
    assert!(
        std::fs::read(&exported).expect("export") == std::fs::read(&exchange).expect("file"),
        "seed {seed}: the export is not the imported file"
    );
    let questioned = write_questioned(&shape, 7, seed, &root, "questioned").expect("query");
    let search = || -> serde_json::Value {
        let out = gonio(&[
            "library",
            "--library",
            s(&library),
            "search",
            s(&questioned),
            "--json",
        ]);
        assert!(
            [0, 3].contains(&code(&out)),
            "seed {seed}: {}",
            stderr(&out)
        );
        serde_json::from_str(&stdout(&out)).expect("one JSON object")
    };
    // What the evidence module gives for the library as it is now.
    let in_process = || -> Vec<(String, f64)> {
        let sheets: Vec<_> = Library::open_file(&library, OpenMode::Existing)
            .expect("library")
            .sheets()
            .expect("sheets")
            .into_iter()
            .map(|(_, sheet)| sheet)
            .collect();
        let (population, _) = validation::validate_or_explain(&sheets).expect("population");
        let measured = host::output::folder::sheet::read_measured(&questioned).expect("query");
        evidence::search(&measured.questioned(), &population)
            .ranking
            .into_iter()
            .map(|r| (r.stock, r.raw_log10_lr))
            .collect()
    };
    let ranking = |v: &serde_json::Value| -> Vec<(String, f64)> {
        v["ranking"]
            .as_array()
            .expect("ranking")
            .iter()
            .map(|r| {
                (
                    r["stock"].as_str().expect("stock").to_string(),
                    r["raw_log10_lr"].as_f64().expect("raw"),
                )
            })
            .collect()
    };
    let same = |a: &[(String, f64)], b: &[(String, f64)], what: &str| {
        assert_eq!(a.len(), b.len(), "seed {seed}: {what}");
        for (x, y) in a.iter().zip(b) {
            assert!(
                x.0 == y.0 && (x.1 - y.1).abs() <= 1e-9 * y.1.abs().max(1.0),
                "seed {seed}: {what}: {x:?} against {y:?}"
            );
        }
    };
    let fresh = search();
    let cached = search();
    assert_eq!(ranking(&fresh).len(), 30, "seed {seed}");
    same(&ranking(&fresh), &in_process(), "the first search");
    same(&ranking(&cached), &ranking(&fresh), "the cached search");
    assert_eq!(fresh["population"], cached["population"], "seed {seed}");
    assert_eq!(fresh["warnings"], cached["warnings"], "seed {seed}");
    // One more sheet of the first stock (its first sheet's readings under another
    // session): other contents, so another population.
    let more = root.join("more.jsonl");
    let lines: String = std::fs::read_to_string(&exchange)
        .expect("file")
        .lines()
        .take(3)
        .map(|l| l.replace(&format!("{:064x}", 1), &format!("{:064x}", 10_000)) + "\n")
        .collect();
    std::fs::write(&more, lines).expect("write");
    let out = gonio(&["library", "--library", s(&library), "import", s(&more)]);
    assert!(out.status.success(), "seed {seed}: {}", stderr(&out));
    let after = search();
    assert_ne!(
        after["population"]["identity"], fresh["population"]["identity"],
        "seed {seed}: the cached population was used for changed contents"
    );
    same(
        &ranking(&after),
        &in_process(),
        "the search after an import",
    );
    let _ = std::fs::remove_dir_all(&root);
}

/// A spot record of the exchange format for `stock`'s sheet `sheet`, spot `spot` of two,
/// laid as `orientation`, `side`; its values a fixed step from one of three papers.
fn laid_record(stock: usize, sheet: usize, spot: usize, orientation: &str, side: &str) -> String {
    let kinds = [[0.8, 57.8, 0.855], [21.7, 0.409, 0.414], [11.0, 0.9, 0.6]];
    let v: [f64; 3] = std::array::from_fn(|i| {
        kinds[stock % 3][i]
            * (1.0 + 0.07 * stock as f64)
            * (1.0 + 0.01 * sheet as f64)
            * (1.0 + 0.005 * spot as f64)
    });
    let cov: Vec<Vec<f64>> = (0..3)
        .map(|r| {
            (0..3)
                .map(|c| if r == c { (v[r] * 0.003).powi(2) } else { 0.0 })
                .collect()
        })
        .collect();
    serde_json::json!({
        "schema": host::schema::LIBRARY_RECORD, "stock": format!("S{stock}"),
        "manufacturer": null, "stock_notes": null,
        "session_sha256": format!("{:064x}", 100 * stock + sheet + 1),
        "sample": format!("S{stock}-{sheet}"), "lot": null, "measured_at": null,
        "orientation": orientation, "side": side,
        "instrument_serial": "SIM-0001", "session_path": format!("s{stock}-{sheet}"),
        "added_at": "2026-12-04T00:00:00.000Z", "spot": spot, "spots": 2,
        "sigma_deg": v[0], "rho_s": v[1], "rho_d": v[2], "covariance": cov,
    })
    .to_string()
}

/// Issue 31: the library records how each sheet lay, from the folder `add` is given and
/// through export and import; a search of a sheet measured in CD against stocks measured
/// in MD warns naming both (and the stocks), a stock of mixed lays is warned of, and the
/// same holds for `compare --library`. Never silent; every output valid in its schema.
#[test]
fn a_cd_sheet_searched_against_md_stocks_is_warned_of_naming_both() {
    let root = temp_dir("library", "lay");
    std::fs::create_dir_all(&root).expect("temp dir");
    // Stocks S0…S3 of two MD felt sheets each; S4 one sheet MD, one CD.
    let mut lines = String::new();
    for stock in 0..5 {
        for sheet in 0..2 {
            let orientation = if stock == 4 && sheet == 1 { "cd" } else { "md" };
            for spot in 0..2 {
                lines += &laid_record(stock, sheet, spot, orientation, "felt");
                lines.push('\n');
            }
        }
    }
    let exchange = root.join("laid.jsonl");
    std::fs::write(&exchange, &lines).expect("write");
    let library = root.join("library.sqlite");
    let out = gonio(&["library", "--library", s(&library), "import", s(&exchange)]);
    assert!(out.status.success(), "{}", stderr(&out));
    // Two sheets measured: one in CD, one in MD, both felt side up.
    let measure_laid = |name: &str, orientation: &str, seed: &str| {
        let dir = root.join(name);
        let out = gonio(&[
            "measure",
            "--spots",
            "1",
            "--sim",
            "PPC",
            "--seed",
            seed,
            "--orientation",
            orientation,
            "--side",
            "felt",
            "--out",
            s(&dir),
        ]);
        assert!(matches!(code(&out), 0 | 3), "{}", stderr(&out));
        dir
    };
    let (q_cd, q_md) = (
        measure_laid("q-cd", "cd", "31"),
        measure_laid("q-md", "md", "32"),
    );
    // `add` records the lay the folder states; `export` writes it.
    let out = gonio(&[
        "library",
        "--library",
        s(&library),
        "add",
        "--allow-flagged",
        "--stock",
        "Q",
        s(&q_md),
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    let exported = root.join("export.jsonl");
    let out = gonio(&["library", "--library", s(&library), "export", s(&exported)]);
    assert!(out.status.success(), "{}", stderr(&out));
    let records: Vec<serde_json::Value> = std::fs::read_to_string(&exported)
        .expect("export")
        .lines()
        .map(|l| serde_json::from_str(l).expect("JSON"))
        .collect();
    let added: Vec<&serde_json::Value> = records.iter().filter(|r| r["stock"] == "Q").collect();
    assert!(!added.is_empty());
    for r in &added {
        assert_eq!(
            (&r["orientation"], &r["side"]),
            (&"md".into(), &"felt".into()),
            "{r}"
        );
        crate::schemas::check_against_its_schema("library export", r);
    }
    // And import carries it: a second library from the export exports the same bytes.
    let second = root.join("second.sqlite");
    let out = gonio(&["library", "--library", s(&second), "import", s(&exported)]);
    assert!(out.status.success(), "{}", stderr(&out));
    let again = root.join("again.jsonl");
    let out = gonio(&["library", "--library", s(&second), "export", s(&again)]);
    assert!(out.status.success(), "{}", stderr(&out));
    assert!(std::fs::read(&again).expect("again") == std::fs::read(&exported).expect("export"));
    // The CD sheet against the MD stocks: said, naming both lays and every stock.
    let out = gonio(&[
        "library",
        "--library",
        s(&library),
        "search",
        "--json",
        s(&q_cd),
    ]);
    assert_eq!(code(&out), 3, "{}", stderr(&out));
    let found: serde_json::Value = serde_json::from_str(&stdout(&out)).expect("JSON");
    crate::schemas::check_against_its_schema("library search --json", &found);
    let warnings = found["warnings"].as_array().expect("warnings");
    let of = |kind: &str| -> Vec<&serde_json::Value> {
        warnings.iter().filter(|w| w["kind"] == kind).collect()
    };
    let differs = of("stock-lay-differs");
    assert_eq!(differs.len(), 1, "{found}");
    let w = differs[0];
    assert_eq!(
        (&w["what"], &w["sheet_lay"], &w["stock_lay"]),
        (&"orientation".into(), &"cd".into(), &"md".into()),
        "{w}"
    );
    assert_eq!(
        w["stocks"],
        serde_json::json!(["Q", "S0", "S1", "S2", "S3"]),
        "{w}"
    );
    let message = w["message"].as_str().expect("message");
    assert!(
        message.contains("A was measured in orientation cd, every sheet of the 5 stocks 'Q', 'S0'")
            && message.contains("in md"),
        "{message}"
    );
    let mixed = of("stock-lay-mixed");
    assert_eq!(mixed.len(), 1, "{found}");
    assert_eq!(
        mixed[0]["stocks"],
        serde_json::json!([{"stock": "S4", "lays": "1 cd, 1 md"}])
    );
    // All felt, as the sheet: nothing said of the side.
    assert!(warnings.iter().all(|w| w["what"] != "side"), "{found}");
    for r in found["ranking"].as_array().expect("ranking") {
        let want = if r["stock"] == "S4" { "mixed" } else { "md" };
        assert_eq!(
            (&r["orientation"], &r["side"]),
            (&want.into(), &"felt".into()),
            "{r}"
        );
    }
    // The table says it too.
    let out = gonio(&["library", "--library", s(&library), "search", s(&q_cd)]);
    assert_eq!(code(&out), 3, "{}", stderr(&out));
    let text = stdout(&out);
    assert!(text.contains("orientation cd, side felt"), "{text}");
    assert!(
        text.contains("warning: A was measured in orientation cd"),
        "{text}"
    );
    assert!(
        text.lines()
            .any(|l| l.contains(" S4 ") && l.contains("mixed felt")),
        "{text}"
    );
    // The MD sheet: in the library itself, left out of its stock; only S4's mix is said.
    let out = gonio(&[
        "library",
        "--library",
        s(&library),
        "search",
        "--json",
        s(&q_md),
    ]);
    let found: serde_json::Value = serde_json::from_str(&stdout(&out)).expect("JSON");
    let kinds: Vec<&str> = found["warnings"]
        .as_array()
        .expect("warnings")
        .iter()
        .filter_map(|w| w["kind"].as_str())
        .filter(|k| k.contains("lay"))
        .collect();
    assert_eq!(kinds, ["stock-lay-mixed"], "{found}");
    // compare --library: each sheet against the stocks, beside A against B.
    let out = gonio(&[
        "compare",
        "--json",
        "--allow-lay-mismatch",
        "--library",
        s(&library),
        s(&q_cd),
        s(&q_md),
    ]);
    assert_eq!(code(&out), 3, "{}", stderr(&out));
    let compared: serde_json::Value = serde_json::from_str(&stdout(&out)).expect("JSON");
    crate::schemas::check_against_its_schema("compare --json", &compared);
    let said: Vec<(String, String)> = compared["warnings"]
        .as_array()
        .expect("warnings")
        .iter()
        .map(|w| {
            (
                w["kind"].as_str().unwrap_or("").into(),
                w["side"].as_str().unwrap_or("").into(),
            )
        })
        .collect();
    for wanted in [
        ("lay-differs", ""),
        ("stock-lay-differs", "A"),
        ("stock-lay-mixed", "A"),
        ("stock-lay-mixed", "B"),
    ] {
        assert!(
            said.contains(&(wanted.0.into(), wanted.1.into())),
            "{wanted:?} in {said:?}"
        );
    }
    assert!(
        !said.contains(&("stock-lay-differs".into(), "B".into())),
        "{said:?}"
    );
    let _ = std::fs::remove_dir_all(&root);
}
