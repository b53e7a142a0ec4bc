//! JSON as an interface: every JSON document gonio prints or writes names its schema, and
//! validates against that schema's JSON Schema in `docs/schemas/` (draft 2020-12, strict:
//! an unknown, renamed or missing key fails). The documents come from real runs of the
//! `gonio` binary over several samples, seeds drawn for this run, the realistic instrument,
//! sheets that are not the model, a sheet of several spots with a flagged spot, link
//! faults, a tile certificate, an unfinished session and damaged folders. A folder written
//! by the first version of the formats (`tests/data/v1-session-G`, as gonio wrote it
//! before documents named their schema) still verifies, re-analyses to the result it
//! reported, and weighs as evidence.
use crate::cli_support;
use crate::common::run_seed;
use cli_support::{gonio, stderr, temp_dir};
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

fn schema_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/schemas")
}

/// Every schema file by its file name, parsed.
fn schema_files() -> BTreeMap<String, Value> {
    let mut out = BTreeMap::new();
    for entry in std::fs::read_dir(schema_dir()).expect("docs/schemas") {
        let path = entry.expect("entry").path();
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        if name.ends_with(".schema.json") {
            let text = std::fs::read_to_string(&path).expect("read a schema");
            out.insert(
                name.clone(),
                serde_json::from_str(&text).unwrap_or_else(|e| panic!("{name}: {e}")),
            );
        }
    }
    out
}

/// The validators of every schema, by schema name (`gonio-session/2`).
struct Schemas {
    validators: BTreeMap<String, jsonschema::Validator>,
}

impl Schemas {
    fn load() -> Schemas {
        let files = schema_files();
        let mut builder = jsonschema::Registry::new();
        for doc in files.values() {
            let id = doc["$id"].as_str().expect("$id").to_string();
            builder = builder.add(id, doc.clone()).expect("a resource");
        }
        let registry = builder.prepare().expect("the schemas resolve");
        let mut validators = BTreeMap::new();
        for (file, doc) in &files {
            let Some(name) = file
                .strip_suffix(".schema.json")
                .filter(|n| *n != "gonio-common")
            else {
                continue;
            };
            // gonio-session-2 → gonio-session/2
            let (base, version) = name.rsplit_once('-').expect("NAME-VERSION");
            let validator = jsonschema::options()
                .with_registry(&registry)
                .build(doc)
                .unwrap_or_else(|e| panic!("{file}: {e}"));
            validators.insert(format!("{base}/{version}"), validator);
        }
        Schemas { validators }
    }

    /// The problems of `doc` against the schema it names (`what` says where it came from).
    fn problems(&self, doc: &Value) -> Vec<String> {
        let Some(name) = host::schema::of(doc) else {
            return vec!["no 'schema'".into()];
        };
        let Some(validator) = self.validators.get(name) else {
            return vec![format!("no JSON Schema for '{name}' in docs/schemas")];
        };
        validator
            .iter_errors(doc)
            .map(|e| format!("{}: {e}", e.instance_path()))
            .collect()
    }

    fn check(&self, what: &str, doc: &Value) {
        let problems = self.problems(doc);
        assert!(
            problems.is_empty(),
            "{what} ({}) does not validate:\n  {}",
            host::schema::of(doc).unwrap_or("?"),
            problems.join("\n  ")
        );
    }

    /// Every JSON file of a session or sheet folder, and every line of points.jsonl.
    fn check_folder(&self, dir: &Path) -> usize {
        let mut checked = 0;
        for entry in std::fs::read_dir(dir).expect("a folder") {
            let path = entry.expect("entry").path();
            let name = path.file_name().unwrap().to_string_lossy().into_owned();
            if path.is_dir() {
                checked += self.check_folder(&path);
            } else if name.ends_with(".json") {
                let doc: Value =
                    serde_json::from_str(&std::fs::read_to_string(&path).expect("read"))
                        .expect("JSON");
                self.check(&path.display().to_string(), &doc);
                checked += 1;
            } else if name.ends_with(".jsonl") {
                for (k, line) in std::fs::read_to_string(&path)
                    .expect("read")
                    .lines()
                    .enumerate()
                {
                    self.check(
                        &format!("{}:{}", path.display(), k + 1),
                        &serde_json::from_str(line).expect("JSON"),
                    );
                    checked += 1;
                }
            }
        }
        checked
    }
}

/// Check `doc` against the JSON Schema it names, strictly, as this file checks every
/// output: for the outputs other test files make (`what` names it in the failure).
pub(crate) fn check_against_its_schema(what: &str, doc: &Value) {
    Schemas::load().check(what, doc);
}

fn json_lines(out: &std::process::Output) -> Vec<Value> {
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l}")))
        .collect()
}

#[test]
fn every_schema_gonio_writes_has_its_file_and_every_file_is_one_gonio_writes() {
    let files = schema_files();
    let mut expected: Vec<String> = host::schema::WRITTEN
        .iter()
        .map(|s| host::schema::file_name(s))
        .collect();
    expected.push(host::schema::file_name(host::schema::TILE_CERTIFICATE));
    expected.push("gonio-common.schema.json".into());
    expected.sort();
    assert_eq!(
        files.keys().cloned().collect::<Vec<_>>(),
        expected,
        "docs/schemas holds exactly the schemas of host::schema"
    );
    for (file, doc) in &files {
        assert_eq!(
            doc["$schema"], "https://json-schema.org/draft/2020-12/schema",
            "{file}"
        );
        assert!(
            doc["$id"]
                .as_str()
                .is_some_and(|id| id.ends_with(&format!("/{file}"))),
            "{file}: $id names the file"
        );
        assert!(
            doc["title"].as_str().is_some_and(|t| !t.is_empty()),
            "{file}: a title"
        );
    }
    let formats =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/FORMATS.md"))
            .expect("docs/FORMATS.md");
    for name in host::schema::WRITTEN
        .iter()
        .chain([&host::schema::TILE_CERTIFICATE])
    {
        assert!(
            formats.contains(&format!("`{name}`")),
            "docs/FORMATS.md does not describe {name}"
        );
        assert!(
            formats.contains(&host::schema::file_name(name)),
            "docs/FORMATS.md does not link the schema of {name}"
        );
    }
}

#[test]
fn every_output_and_file_of_real_sessions_validates_against_its_schema() {
    let schemas = Schemas::load();
    let seed = run_seed().to_string();
    let root = temp_dir("schemas", "sessions");
    std::fs::create_dir_all(&root).unwrap();
    let certificate = root.join("tile.json");
    let today = chrono::Local::now().date_naive();
    std::fs::write(
        &certificate,
        serde_json::json!({
            "tile": "PTFE tile #42", "certificate": "CAL-1", "issued_by": "a laboratory",
            "issued": (today - chrono::Days::new(30)).to_string(), "valid_until": (today + chrono::Days::new(300)).to_string(),
            "radiance_factor": 0.987, "expanded_uncertainty": 0.008, "coverage_factor": 2
        })
        .to_string(),
    )
    .unwrap();
    let cert = certificate.to_str().unwrap();
    // One spot each: the glossy and rough papers, every policy (sweeps with a lossy link), the realistic instrument,
    // sheets that are not the model, a fault on the link, a tile certificate.
    let spots: [(&str, Vec<&str>); 8] = [
        ("g", vec!["--sim", "G"]),
        (
            "sg-sweep",
            vec!["--sim", "SG", "--policy", "sweep", "--faults", "drop=0.001"],
        ),
        ("ppc", vec!["--sim", "PPC", "--policy", "paper"]),
        ("j2-real", vec!["--sim", "J2", "--physics", "real"]),
        (
            "g-cauchy",
            vec!["--sim", "G", "--physics", "real", "--lobe", "cauchy"],
        ),
        (
            "sg-bump",
            vec![
                "--sim",
                "SG",
                "--specular-bump",
                "0.3",
                "--faults",
                "corrupt=0.002,drop=0.002",
            ],
        ),
        (
            "j1-steps",
            vec![
                "--sim",
                "J1",
                "--faults",
                "lose-steps=detector:40",
                "--tile-certificate",
                cert,
            ],
        ),
        (
            "custom",
            vec!["--sim", "custom:4,0.6,0.7,1.5", "--arm-offset", "0.3"],
        ),
    ];
    let mut measure_json = 0;
    for (name, args) in &spots {
        let dir = root.join(name);
        let mut argv = vec![
            "measure",
            "--spots",
            "1",
            "--json",
            "--seed",
            &seed,
            "--out",
            dir.to_str().unwrap(),
        ];
        argv.extend(args.iter().copied());
        let out = gonio(&argv);
        assert!(
            matches!(out.status.code(), Some(0 | 3)),
            "{name}: {}",
            stderr(&out)
        );
        let printed = json_lines(&out);
        assert_eq!(printed.len(), 1, "{name}");
        assert_eq!(
            host::schema::of(&printed[0]),
            Some(host::schema::SPOT_RESULT)
        );
        schemas.check(&format!("measure --json of {name}"), &printed[0]);
        measure_json += 1;
        // The object printed is the session's result, the same in session.json.
        let doc: Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join("session.json")).unwrap())
                .unwrap();
        assert_eq!(
            doc["result"], printed[0],
            "{name}: --json and session.json's result differ"
        );
        assert!(schemas.check_folder(&dir) > 3, "{name}");
    }
    let certified: Value = serde_json::from_str(
        &std::fs::read_to_string(root.join("j1-steps/calibration.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(
        certified["white_certificate"]["certificate"], "CAL-1",
        "the certificate is recorded"
    );
    // A sheet of three spots on the realistic instrument, with a case.
    let sheet = root.join("sheet");
    let out = gonio(&[
        "measure",
        "--sim",
        "SG",
        "--spots",
        "3",
        "--physics",
        "real",
        "--json",
        "--seed",
        &seed,
        "--case",
        "K-1",
        "--operator",
        "A. B.",
        "--orientation",
        "md",
        "--side",
        "felt",
        "--out",
        sheet.to_str().unwrap(),
    ]);
    assert!(matches!(out.status.code(), Some(0 | 3)), "{}", stderr(&out));
    let printed = json_lines(&out);
    assert_eq!(
        host::schema::of(&printed[0]),
        Some(host::schema::SHEET_RESULT)
    );
    schemas.check("measure --json of a sheet", &printed[0]);
    assert!(schemas.check_folder(&sheet) > 10);
    // The sheet's answer, named, in the file and the --json; the mean as an array (as
    // gonio-sheet/2 wrote it) or an answer without its class is not this version.
    let sheet_doc: Value =
        serde_json::from_str(&std::fs::read_to_string(sheet.join("sheet.json")).unwrap()).unwrap();
    assert_eq!(sheet_doc["case"]["orientation"], "md");
    assert_eq!(
        sheet_doc["result"]["answer"], printed[0]["answer"],
        "the --json's answer is the file's"
    );
    assert!(sheet_doc["result"]["mean"]["sigma_deg"].is_number());
    let mut as_array = sheet_doc.clone();
    as_array["result"]["mean"] = serde_json::json!([1.0, 2.0, 3.0]);
    let mut no_class = sheet_doc.clone();
    _ = no_class["result"]["answer"]
        .as_object_mut()
        .unwrap()
        .remove("class");
    for (what, doc) in [
        ("the mean as an array", as_array),
        ("an answer without class", no_class),
    ] {
        assert!(
            !schemas.problems(&doc).is_empty(),
            "{what} passed the schema"
        );
    }
    // An unfinished session: the cable pulled for longer than the host waits.
    let unfinished = root.join("unfinished");
    let out = gonio(&[
        "measure",
        "--sim",
        "G",
        "--spots",
        "1",
        "--seed",
        &seed,
        "--faults",
        "unplug-at=3:60",
        "--out",
        unfinished.to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    schemas.check_folder(&unfinished);

    let dirs: Vec<String> = spots
        .iter()
        .map(|(n, _)| root.join(n).display().to_string())
        .collect();
    let dir = |k: usize| dirs[k].as_str();
    // gonio fit: CSV files (one with no acceptance), then folders.
    let csv = Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/data/bench-40.csv");
    for args in [
        vec!["fit", "--json", csv.to_str().unwrap()],
        vec![
            "fit",
            "--json",
            "--acceptance",
            "0",
            "--delta",
            "2",
            csv.to_str().unwrap(),
        ],
        vec!["fit", "--json", dir(0), dir(1), sheet.to_str().unwrap()],
    ] {
        let out = gonio(&args);
        let lines = json_lines(&out);
        assert!(!lines.is_empty(), "{args:?}: {}", stderr(&out));
        for line in &lines {
            assert_eq!(host::schema::of(line), Some(host::schema::ANALYSIS));
            schemas.check(&format!("{args:?}"), line);
        }
    }
    // gonio compare: two sessions, a sheet against a session.
    for (a, b) in [(dir(0), dir(6)), (sheet.to_str().unwrap(), dir(4))] {
        let out = gonio(&["compare", "--json", "--demo-population", a, b]);
        assert!(matches!(out.status.code(), Some(0 | 3)), "{}", stderr(&out));
        schemas.check("compare --json", &json_lines(&out)[0]);
    }
    // gonio verify: folders that pass and folders that do not.
    let damaged = root.join("damaged");
    let out = std::process::Command::new("cp")
        .arg("-r")
        .arg(dir(2))
        .arg(&damaged)
        .status()
        .expect("cp");
    assert!(out.success());
    std::fs::write(
        damaged.join("readings.csv"),
        "theta_i,theta_r,radiance_factor,std\n1,2,3,4\n",
    )
    .unwrap();
    let out = gonio(&[
        "verify",
        "--json",
        dir(0),
        sheet.to_str().unwrap(),
        damaged.to_str().unwrap(),
        unfinished.to_str().unwrap(),
    ]);
    let lines = json_lines(&out);
    assert_eq!(lines.len(), 4);
    assert_eq!(
        lines.iter().map(|l| l["ok"].as_bool()).collect::<Vec<_>>(),
        [Some(true), Some(true), Some(false), Some(false)]
    );
    for line in &lines {
        schemas.check("verify --json", line);
    }
    // gonio sessions, readable and unreadable folders among them.
    std::fs::create_dir_all(root.join("broken")).unwrap();
    std::fs::write(root.join("broken/session.json"), "{").unwrap();
    let lines = json_lines(&gonio(&["sessions", "--json", root.to_str().unwrap()]));
    assert!(lines.len() >= spots.len() + 2, "{lines:?}");
    assert!(
        lines.iter().any(|l| l["problem"].is_string()),
        "the broken folder is listed as unreadable"
    );
    for line in &lines {
        schemas.check("sessions --json", line);
    }
    // gonio library: add, list, search, export.
    let library = root.join("library.sqlite");
    let lib = library.to_str().unwrap();
    // Seven stocks: a population needs four whose sheets determined σ, ρs and ρd, and some
    // of these sessions are flagged (added with --allow-flagged) or leave a parameter out.
    for (stock, folder) in [
        ("G", dir(0)),
        ("SG", sheet.to_str().unwrap()),
        ("PPC", dir(1)),
        ("J2", dir(2)),
        ("X3", dir(3)),
        ("X4", dir(4)),
        ("X5", dir(5)),
    ] {
        let out = gonio(&[
            "library",
            "--library",
            lib,
            "add",
            "--allow-flagged",
            "--stock",
            stock,
            folder,
        ]);
        assert!(out.status.success(), "{}", stderr(&out));
    }
    schemas.check(
        "library list --json",
        &json_lines(&gonio(&["library", "--library", lib, "list", "--json"]))[0],
    );
    let search = gonio(&["library", "--library", lib, "search", "--json", dir(6)]);
    let found = json_lines(&search);
    assert!(!found.is_empty(), "library search: {}", stderr(&search));
    schemas.check("library search --json", &found[0]);
    // The trail, and the state the search weighed recovered from it alone (issue 29).
    schemas.check(
        "library history --json",
        &json_lines(&gonio(&["library", "--library", lib, "history", "--json"]))[0],
    );
    let state = &found[0]["library_state"];
    let entry = state["audit_entry"]
        .as_i64()
        .expect("the search names its audit entry");
    let at = json_lines(&gonio(&[
        "library",
        "--library",
        lib,
        "history",
        "--contents-at",
        &entry.to_string(),
        "--population",
        "--json",
    ]));
    schemas.check("library history --contents-at --json", &at[0]);
    assert_eq!(
        at[0]["contents"], state["contents"],
        "the contents a search weighed, recovered from the trail"
    );
    assert_eq!(
        at[0]["population"], found[0]["population"]["identity"],
        "and the population it used, made again from them"
    );
    let export = root.join("export.jsonl");
    assert!(
        gonio(&[
            "library",
            "--library",
            lib,
            "export",
            export.to_str().unwrap()
        ])
        .status
        .success()
    );
    let records: Vec<Value> = std::fs::read_to_string(&export)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert!(records.len() >= 6);
    for record in &records {
        schemas.check("library export", record);
    }
    eprintln!("{measure_json} measure outputs, their folders and every other output validated");
    let _ = std::fs::remove_dir_all(&root);
}

#[test]
fn the_schemas_are_strict_an_unknown_a_renamed_or_a_missing_key_fails() {
    let schemas = Schemas::load();
    let root = temp_dir("schemas", "strict");
    let out = gonio(&[
        "measure",
        "--sim",
        "G",
        "--spots",
        "1",
        "--json",
        "--out",
        root.to_str().unwrap(),
    ]);
    // Its seed drawn for the run: a flagged result is a result of the schema too.
    cli_support::assert_finished(&out);
    let good = &json_lines(&out)[0];
    assert!(schemas.problems(good).is_empty());
    let mutate = |f: &dyn Fn(&mut Value)| {
        let mut v = good.clone();
        f(&mut v);
        v
    };
    let bad = [
        ("an unknown key", mutate(&|v| v["colour"] = "white".into())),
        (
            "σ's interval under its old name",
            mutate(&|v| v["ci95"]["sigma"] = v["ci95"]["sigma_deg"].take()),
        ),
        (
            "refinements as bare numbers",
            mutate(&|v| v["refinements"] = serde_json::json!([8])),
        ),
        (
            "a missing key",
            mutate(&|v| _ = v.as_object_mut().unwrap().remove("class")),
        ),
        ("a number as text", mutate(&|v| v["rho_d"] = "0.8".into())),
        (
            "an unknown flag",
            mutate(&|v| v["flags"] = serde_json::json!(["wobbly"])),
        ),
        (
            "another schema",
            mutate(&|v| v["schema"] = host::schema::ANALYSIS.into()),
        ),
        (
            "an unknown budget term's key",
            mutate(&|v| v["budget"]["terms"][0]["extra"] = 1.into()),
        ),
    ];
    for (what, doc) in &bad {
        assert!(
            !schemas.problems(doc).is_empty(),
            "{what} passed the schema"
        );
    }
    // A mark of points.jsonl, as the record writes it.
    let mark = host::output::folder::mark_line(&host::output::folder::SupersedeMark {
        superseded: vec![0, 3],
        why: "lost steps".into(),
    })
    .unwrap();
    schemas.check("a mark line", &serde_json::from_str(&mark).unwrap());
    let mut unmarked: Value = serde_json::from_str(&mark).unwrap();
    unmarked["superseded"] = serde_json::json!([]);
    assert!(!schemas.problems(&unmarked).is_empty(), "a mark of nothing");
    let _ = std::fs::remove_dir_all(&root);
}

/// The v1 fixture copied to a temporary folder (tests must not write into the source tree).
fn v1_copy(name: &str) -> PathBuf {
    let dir = temp_dir("schemas", name).join("v1-session");
    std::fs::create_dir_all(&dir).unwrap();
    for entry in
        std::fs::read_dir(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/v1-session-G"))
            .unwrap()
    {
        let path = entry.unwrap().path();
        std::fs::copy(&path, dir.join(path.file_name().unwrap())).unwrap();
    }
    dir
}

#[test]
fn a_folder_of_the_first_version_verifies_reanalyses_reports_and_compares() {
    let dir = v1_copy("v1");
    let d = dir.to_str().unwrap();
    let doc: Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("session.json")).unwrap()).unwrap();
    assert_eq!(
        doc["format"],
        host::schema::SESSION_V1,
        "the fixture is of the first version"
    );
    let out = gonio(&["verify", "--json", d]);
    assert!(out.status.success(), "{}", stderr(&out));
    // Analysed again, it gives the result that session reported, under today's names.
    let lines = json_lines(&gonio(&["fit", "--json", d]));
    assert_eq!(lines[0]["same_as_session"], true, "{}", lines[0]);
    assert!(lines[0]["ci95"]["sigma_deg"].is_array(), "{}", lines[0]);
    Schemas::load().check("fit --json of a v1 folder", &lines[0]);
    let out = gonio(&["report", d]);
    assert!(out.status.success(), "{}", stderr(&out));
    assert!(
        std::fs::read_to_string(dir.join("report.html"))
            .unwrap()
            .contains("Sample G")
    );
    // Compared with itself: computed, and warned that it is one measurement (exit 3).
    let out = gonio(&["compare", "--json", "--demo-population", d, d]);
    assert_eq!(out.status.code(), Some(3), "{}", stderr(&out));
    let lines = json_lines(&gonio(&[
        "sessions",
        "--json",
        dir.parent().unwrap().to_str().unwrap(),
    ]));
    assert!(
        lines.iter().any(
            |l| l["dir"].as_str().is_some_and(|p| p.ends_with("v1-session"))
                && l["classes"] == serde_json::json!(["G"])
        ),
        "{lines:?}"
    );
    // A newer version than this gonio reads is refused with what to do.
    let newer = v1_copy("v3");
    let text = std::fs::read_to_string(newer.join("session.json"))
        .unwrap()
        .replace(host::schema::SESSION_V1, "gonio-session/4");
    std::fs::write(newer.join("session.json"), text).unwrap();
    let out = gonio(&["fit", newer.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(1));
    assert!(
        stderr(&out).contains("'gonio-session/4'") && stderr(&out).contains("update gonio"),
        "{}",
        stderr(&out)
    );
    let _ = std::fs::remove_dir_all(dir.parent().unwrap());
    let _ = std::fs::remove_dir_all(newer.parent().unwrap());
}

/// `gonio characterize`'s profile on drawn instruments (a seed per run), and a session's
/// result with that profile in force (its `gloss` and `analysis_settings.instrument_profile`)
/// and without one (its `instrument_bound`), against their JSON Schemas.
#[test]
fn instrument_profiles_and_the_sessions_that_use_them_validate() {
    let schemas = Schemas::load();
    let seed = run_seed().to_string();
    let root = temp_dir("schemas", "instrument");
    std::fs::create_dir_all(&root).unwrap();
    let profile = root.join("instrument.json");
    let out = gonio(&[
        "characterize",
        "--sim",
        "--physics",
        "drawn",
        "--seed",
        &seed,
        "--rehomes",
        "1",
        "--lamp-s",
        "4",
        "--out",
        profile.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    let doc: Value = serde_json::from_slice(&std::fs::read(&profile).unwrap()).unwrap();
    schemas.check("instrument.json", &doc);
    for (name, extra) in [
        ("with", vec!["--instrument", profile.to_str().unwrap()]),
        ("without", vec![]),
    ] {
        let folder = root.join(name);
        let mut args = vec![
            "measure",
            "--sim",
            "SG",
            "--physics",
            "drawn",
            "--seed",
            &seed,
            "--spots",
            "1",
            "--json",
            "--out",
            folder.to_str().unwrap(),
        ];
        args.extend(extra);
        let out = gonio(&args);
        let result: Value = serde_json::from_slice(&out.stdout)
            .unwrap_or_else(|e| panic!("{name}: {e}: {}", stderr(&out)));
        schemas.check(&format!("measure --json {name} a profile"), &result);
        assert_eq!(result.get("gloss").is_some(), name == "with", "{result}");
        assert_eq!(
            result.get("instrument_bound").is_some(),
            name == "without",
            "{result}"
        );
        schemas.check_folder(&folder);
    }
}

#[test]
fn keys_public_keys_and_signatures_validate() {
    let schemas = Schemas::load();
    let keys = temp_dir("schemas", "keys");
    let run = |args: &[&str]| {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_gonio"))
            .args(args)
            .env("GONIO_KEYS_DIR", &keys)
            .output()
            .expect("run gonio");
        assert!(out.status.success(), "{}", stderr(&out));
        out
    };
    let read = |p: PathBuf| -> Value {
        serde_json::from_str(&std::fs::read_to_string(&p).expect("read")).expect("JSON")
    };
    run(&["keys", "new", "lab"]);
    schemas.check("lab.key", &read(keys.join("lab.key")));
    let exported = run(&["keys", "export-public", "lab"]);
    let public: Value = serde_json::from_slice(&exported.stdout).expect("JSON");
    schemas.check("keys export-public", &public);
    let hex = public["public_key"].as_str().unwrap().to_string();
    run(&["keys", "trust", &hex, "--name", "remote"]);
    // Under a name of one's own keys it is refused; under another it is kept as NAME.pub.
    schemas.check("remote.pub", &read(keys.join("remote.pub")));
    let signer = host::output::folder::signature::Keys::at(&keys)
        .load("lab")
        .unwrap();
    let doc = serde_json::to_value(signer.sign("MANIFEST.sha256", b"x")).unwrap();
    schemas.check("signature.json", &doc);
}

/// `gonio batch`'s `batch.json` (and `--json`), with every sheet folder in the batch
/// folder, against their JSON Schemas: sheets of the master's paper (pass) with the
/// instrument's profile (their gloss judged against a specification), and of another
/// paper (fail, the parameters named, the gloss not judged without a profile).
#[test]
fn a_batch_and_its_sheet_folders_validate() {
    let schemas = Schemas::load();
    let seed = run_seed();
    let root = temp_dir("schemas", "batch");
    std::fs::create_dir_all(&root).unwrap();
    let library = crate::batch::library_with_master(&root, "Stock-SG", "SG", 2, seed);
    let profile = crate::batch::simulated_profile(&root, seed);
    let with_profile = ["--instrument", profile.to_str().unwrap()];
    let seed_text = seed.to_string();
    for (name, paper, spots, extra) in [
        ("same", "SG", "2", &with_profile[..]),
        ("other", "G", "1", &[][..]),
    ] {
        let dir = root.join(name);
        let mut args = vec![
            "batch",
            "--library",
            library.to_str().unwrap(),
            "--master",
            "Stock-SG",
            "--sim",
            paper,
            "--sheets",
            "2",
            "--spots",
            spots,
            "--seed",
            &seed_text,
            "--out",
            dir.to_str().unwrap(),
            "--json",
            "--gloss-spec",
            "60=11±5",
        ];
        args.extend_from_slice(extra);
        let out = gonio(&args);
        assert!(matches!(out.status.code(), Some(0 | 3)), "{}", stderr(&out));
        let printed = json_lines(&out);
        assert_eq!(printed.len(), 1);
        schemas.check("gonio batch --json", &printed[0]);
        let written: Value =
            serde_json::from_slice(&std::fs::read(dir.join("batch.json")).unwrap()).unwrap();
        assert_eq!(written, printed[0], "--json prints batch.json");
        // batch.json and every JSON file of every sheet folder.
        let checked = schemas.check_folder(&dir);
        assert!(checked > 4, "{checked} documents");
        let judged = written["sheets"][0]["gloss_judgements"][0]["verdict"].clone();
        assert!(
            if paper == "G" {
                judged == "undecided"
            } else {
                !written["sheets"][0]["gloss"].as_array().unwrap().is_empty()
            },
            "{written}"
        );
        if paper == "G" {
            assert!(
                written["sheets"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .any(|s| s["verdict"] == "fail"),
                "{written}"
            );
        }
    }
    let _ = std::fs::remove_dir_all(&root);
}
