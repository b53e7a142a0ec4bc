//! `gonio batch` end to end, as a paper-QA bench runs it: a master stock put in the test's
//! own library from simulated sheets, then batches of sheets judged against it — of the
//! same paper (they pass), of another paper (they fail, naming the parameter), one
//! interrupted and resumed, bad input refused, and the batch report in a headless browser.
use crate::cli_support;
use crate::common::run_seed;
use cli_support::{gonio, stderr, temp_dir};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

fn s(path: &Path) -> &str {
    path.to_str().expect("a UTF-8 temp path")
}

fn code(out: &std::process::Output) -> i32 {
    out.status.code().expect("exited")
}

/// A library at `root/library.sqlite` with the stock `stock`: `sheets` sheets of two spots
/// of `paper` measured on the simulator, seeds from `seed + 1000`. A master is made of
/// clean sheets (`library add` refuses a flagged one): a sheet flagged on its seed, which
/// the analysis does at its false-alarm rate on a paper measured right (a spot's
/// lack-of-fit, about 2 in 1,000 seeds of PPC), is left out and the next seed measured in
/// its place.
pub fn library_with_master(
    root: &Path,
    stock: &str,
    paper: &str,
    sheets: u64,
    seed: u64,
) -> PathBuf {
    let library = root.join("library.sqlite");
    let mut dirs = Vec::new();
    let mut next = seed + 1000;
    for k in 0..sheets {
        let dir = root.join(format!("master-{stock}-{k}"));
        for attempt in 1.. {
            let _ = std::fs::remove_dir_all(&dir);
            let out = gonio(&[
                "measure",
                "--sim",
                paper,
                "--spots",
                "2",
                "--seed",
                &next.to_string(),
                "--out",
                s(&dir),
            ]);
            next += 1;
            cli_support::assert_finished(&out);
            if code(&out) == 0 {
                break;
            }
            assert!(
                attempt < 4,
                "master sheet {k}: 4 seeds in a row flagged, to {}: {}",
                next - 1,
                stderr(&out)
            );
        }
        dirs.push(dir);
    }
    let mut args = vec!["library", "add", "--library", s(&library), "--stock", stock];
    args.extend(dirs.iter().map(|d| s(d)));
    let out = gonio(&args);
    assert!(out.status.success(), "library add: {}", stderr(&out));
    library
}

fn batch_json(dir: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(dir.join("batch.json")).expect("batch.json");
    serde_json::from_str(&text).expect("JSON")
}

/// `gonio batch` of `sheets` sheets of `paper` against `master`, in `out`, with `extra`
/// (default: two spots a sheet).
fn batch(
    library: &Path,
    master: &str,
    paper: &str,
    sheets: &str,
    out: &Path,
    seed: u64,
    extra: &[&str],
) -> std::process::Output {
    let seed = seed.to_string();
    let mut args = vec![
        "batch",
        "--library",
        s(library),
        "--master",
        master,
        "--sim",
        paper,
        "--sheets",
        sheets,
        "--seed",
        &seed,
        "--out",
        s(out),
    ];
    args.extend_from_slice(extra);
    if !extra.contains(&"--spots") {
        args.extend(["--spots", "2"]);
    }
    gonio(&args)
}

#[test]
fn sheets_of_the_master_s_paper_pass_and_of_another_paper_fail_naming_the_parameter() {
    let seed = run_seed();
    let root = temp_dir("batch", "verdicts");
    let library = library_with_master(&root, "Stock-SG", "SG", 2, seed);

    // Sheets of the master's own paper, the simulator's sheets all the paper (no lot
    // spread: the master's sheets had none either): every one within the tolerances.
    let same = root.join("same");
    let out = batch(
        &library,
        "Stock-SG",
        "SG",
        "3",
        &same,
        seed,
        &["--sheet-to-sheet-pct", "0"],
    );
    let doc = batch_json(&same);
    assert_eq!(doc["status"], "finished", "{doc}");
    let sheets = doc["sheets"].as_array().expect("sheets");
    assert_eq!(sheets.len(), 3);
    // A sheet whose own result is flagged is undecided, never a pass or a fail. A sheet of
    // the master's paper may fail: the default tolerance is 3 of the master's standard
    // deviations (the Shewhart convention, analysis/batch.rs), about 0.3 % of judgements
    // beyond it, and 9 judgements (3 sheets × σ, ρs, ρd) make that 2.7 % of runs (run seed
    // 40295: ρs 16.58 % off against a tolerance of 16.5 %); two fails of 9 are 0.04 %.
    let mut failed = 0;
    for sheet in sheets {
        match sheet["verdict"].as_str() {
            Some("pass") => {}
            Some("fail") => failed += 1,
            _ => assert!(
                sheet["verdict"] == "undecided" && !sheet["flags"].as_array().unwrap().is_empty(),
                "a sheet of the master's paper: {sheet}"
            ),
        }
    }
    assert!(
        failed <= 1,
        "{failed} sheets of the master's paper failed: {doc}"
    );
    let passed = sheets.iter().filter(|s| s["verdict"] == "pass").count();
    assert!(passed >= 2, "{doc}");
    assert_eq!(
        code(&out),
        if passed == 3 { 0 } else { 3 },
        "{}",
        stderr(&out)
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        stdout.contains("PASS") && stdout.contains("Stock-SG"),
        "{stdout}"
    );
    // Statistics over the clean sheets, with I-MR limits about their mean.
    for st in doc["statistics"].as_array().expect("statistics") {
        let (mean, lo, hi) = (
            st["mean"].as_f64().unwrap(),
            st["lower_control_limit"].as_f64().unwrap(),
            st["upper_control_limit"].as_f64().unwrap(),
        );
        assert!(lo <= mean && mean <= hi, "{st}");
    }
    // Each sheet is a sheet folder that verifies on its own.
    let verified = gonio(&["verify", s(&same.join("sheet-02"))]);
    assert!(verified.status.success(), "{}", stderr(&verified));

    // Sheets of G (σ 0.8° against SG's 1.9°): every judged sheet fails, naming σ.
    let other = root.join("other");
    let out = batch(&library, "Stock-SG", "G", "2", &other, seed, &[]);
    assert_eq!(code(&out), 3, "{}", stderr(&out));
    let doc = batch_json(&other);
    for sheet in doc["sheets"].as_array().expect("sheets") {
        if sheet["verdict"] == "undecided" {
            continue;
        }
        assert_eq!(sheet["verdict"], "fail", "{sheet}");
        let exceeded = sheet["exceeded"].as_array().expect("exceeded");
        let sigma = exceeded
            .iter()
            .find(|e| e["parameter"] == "sigma_deg")
            .unwrap_or_else(|| panic!("σ named: {sheet}"));
        let deviation = sigma["deviation_pct"].as_f64().unwrap();
        assert!((-65.0..-50.0).contains(&deviation), "{sigma}");
        assert!(
            (sigma["beyond_pct"].as_f64().unwrap()
                - (deviation.abs() - sigma["tolerance_pct"].as_f64().unwrap()))
            .abs()
                < 1e-9
        );
    }
    assert!(doc["counts"]["fail"].as_u64().unwrap() >= 1, "{doc}");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("FAIL: σ"), "{stdout}");

    // The spreadsheet: one row per sheet, units in the headers, the failed parameter named.
    let mut csv = csv::Reader::from_path(other.join("batch.csv")).expect("batch.csv");
    let headers = csv.headers().expect("headers").clone();
    for wanted in [
        "sigma (deg)",
        "rho_s (1)",
        "rho_d (1)",
        "sigma deviation (%)",
        "verdict",
        "failed parameters",
    ] {
        assert!(
            headers.iter().any(|h| h == wanted),
            "{wanted} in {headers:?}"
        );
    }
    let rows: Vec<csv::StringRecord> = csv.records().map(|r| r.expect("a row")).collect();
    assert_eq!(rows.len(), 2);
    let at = |name: &str| headers.iter().position(|h| h == name).unwrap();
    for row in &rows {
        if &row[at("verdict")] == "fail" {
            assert!(
                row[at("failed parameters")].contains("sigma_deg"),
                "{row:?}"
            );
            let sigma: f64 = row[at("sigma (deg)")].parse().expect("a number");
            assert!((0.6..1.0).contains(&sigma), "{row:?}");
        }
    }
    let _ = std::fs::remove_dir_all(&root);
}

/// The sheets the simulator draws for a batch differ as sheets of a lot do: each its own
/// σ, ρs and ρd about the paper, recorded in batch.json.
#[test]
fn simulated_sheets_of_a_batch_are_drawn_about_the_paper() {
    let seed = run_seed();
    let root = temp_dir("batch", "drawn");
    let library = library_with_master(&root, "PPC-master", "PPC", 1, seed);
    let out_dir = root.join("drawn");
    let out = batch(
        &library,
        "PPC-master",
        "PPC",
        "3",
        &out_dir,
        seed,
        &["--sheet-to-sheet-pct", "5", "--spots", "1"],
    );
    assert!(matches!(code(&out), 0 | 3), "{}", stderr(&out));
    let doc = batch_json(&out_dir);
    let drawn: Vec<String> = doc["sheets"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| {
            s["simulated"]
                .as_str()
                .expect("the drawn sheet")
                .to_string()
        })
        .collect();
    assert_eq!(drawn.len(), 3);
    assert!(drawn[0] != drawn[1] && drawn[1] != drawn[2], "{drawn:?}");
    for d in &drawn {
        let v: Vec<f64> = d
            .trim_start_matches("custom:")
            .split(',')
            .map(|x| x.parse().unwrap())
            .collect();
        // PPC: σ 21.7°, ρs 0.409, ρd 0.414; 5 % about it is within ±25 % for any seed
        // but one in millions.
        for (got, paper) in v.iter().zip([21.7, 0.409, 0.414, 3.0]) {
            assert!((got / paper - 1.0).abs() < 0.25, "{d}");
        }
    }
    assert_eq!(doc["plan"]["sheet_to_sheet_pct"], 5.0);
    let _ = std::fs::remove_dir_all(&root);
}

#[test]
fn an_interrupted_batch_resumes_at_the_sheet_it_stopped_in_and_keeps_the_sheets_before() {
    let seed = run_seed();
    let root = temp_dir("batch", "resume");
    let library = library_with_master(&root, "Stock-SG", "SG", 1, seed);
    let dir = root.join("batch");
    let seed_text = seed.to_string();
    let child = Command::new(env!("CARGO_BIN_EXE_gonio"))
        .args([
            "batch",
            "--library",
            s(&library),
            "--master",
            "Stock-SG",
            "--sim",
            "SG",
            "--sheets",
            "4",
            "--spots",
            "2",
            "--seed",
            &seed_text,
            "--out",
            s(&dir),
        ])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run gonio batch");
    // Ctrl-C once sheet 1 is judged and recorded.
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(300);
    loop {
        let recorded = std::fs::read_to_string(dir.join("batch.json"))
            .ok()
            .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
            .is_some_and(|d| d["sheets"].as_array().is_some_and(|s| !s.is_empty()));
        if recorded {
            break;
        }
        assert!(
            std::time::Instant::now() < deadline,
            "sheet 1 never recorded"
        );
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let killed = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .expect("kill");
    assert!(killed.success());
    let out = child.wait_with_output().expect("gonio batch ends");
    assert_eq!(code(&out), 130, "{}", stderr(&out));
    let doc = batch_json(&dir);
    assert_eq!(doc["status"], "interrupted", "{doc}");
    let stopped_at = doc["sheets"].as_array().unwrap().len();
    assert!((1..4).contains(&stopped_at), "{doc}");
    let resume_with = doc["resume_with"].as_str().expect("how to continue");
    assert!(
        resume_with.contains("gonio batch --sim SG --resume"),
        "{resume_with}"
    );
    assert!(stderr(&out).contains("continue with"), "{}", stderr(&out));
    let manifest_1 = std::fs::read(dir.join("sheet-01/MANIFEST.sha256")).expect("sheet 1 finished");

    let out = gonio(&[
        "batch",
        "--library",
        s(&library),
        "--sim",
        "SG",
        "--resume",
        s(&dir),
    ]);
    assert!(matches!(code(&out), 0 | 3), "{}", stderr(&out));
    let doc = batch_json(&dir);
    assert_eq!(doc["status"], "finished", "{doc}");
    let sheets = doc["sheets"].as_array().unwrap();
    assert_eq!(sheets.len(), 4);
    for (k, sheet) in sheets.iter().enumerate() {
        assert_eq!(sheet["number"], k + 1);
        let folder = dir.join(sheet["folder"].as_str().unwrap());
        let verified = gonio(&["verify", s(&folder)]);
        assert!(
            verified.status.success(),
            "{}: {}",
            folder.display(),
            stderr(&verified)
        );
    }
    assert_eq!(
        std::fs::read(dir.join("sheet-01/MANIFEST.sha256")).unwrap(),
        manifest_1,
        "sheet 1 is not measured again"
    );
    // Resumed or new, the sheet the batch stopped in went on as the batch's sheet.
    let resumed = String::from_utf8_lossy(&out.stderr);
    assert!(
        !resumed.contains("batch: sheet 1 of"),
        "sheet 1 measured again: {resumed}"
    );
    // A finished batch is not continued.
    let again = gonio(&[
        "batch",
        "--library",
        s(&library),
        "--sim",
        "SG",
        "--resume",
        s(&dir),
    ]);
    assert_eq!(code(&again), 1);
    assert!(
        stderr(&again).contains("the batch is finished"),
        "{}",
        stderr(&again)
    );
    let _ = std::fs::remove_dir_all(&root);
}

#[test]
fn bad_input_is_refused_before_anything_is_measured() {
    let root = temp_dir("batch", "bad");
    std::fs::create_dir_all(&root).unwrap();
    let missing = root.join("no-library.sqlite");
    let out_dir = root.join("out");
    let run = |library: &Path, master: &str, sheets: &str| {
        gonio(&[
            "batch",
            "--library",
            s(library),
            "--master",
            master,
            "--sim",
            "SG",
            "--sheets",
            sheets,
            "--out",
            s(&out_dir),
        ])
    };
    // An empty (missing) library.
    let out = run(&missing, "Stock-SG", "2");
    assert_eq!(code(&out), 1);
    assert!(
        stderr(&out).contains("no library here yet"),
        "{}",
        stderr(&out)
    );
    assert!(!out_dir.exists(), "nothing written");
    // No sheets.
    // The command line wrong: exit 2, as the README's table says for every subcommand.
    let out = run(&missing, "Stock-SG", "0");
    assert_eq!(code(&out), 2);
    assert!(
        stderr(&out).contains("--sheets must be 1 to 999, not 0"),
        "{}",
        stderr(&out)
    );
    // An unknown stock: named, with the stocks the library holds.
    let library = library_with_master(&root, "Stock-SG", "SG", 1, 7);
    let out = run(&library, "Stock-XX", "2");
    assert_eq!(code(&out), 1);
    let err = stderr(&out);
    assert!(
        err.contains("no stock 'Stock-XX'") && err.contains("Stock-SG"),
        "{err}"
    );
    assert!(!out_dir.exists(), "nothing written");
    // A tolerance that is no tolerance.
    let out = gonio(&[
        "batch",
        "--library",
        s(&library),
        "--master",
        "Stock-SG",
        "--sim",
        "SG",
        "--sheets",
        "2",
        "--out",
        s(&out_dir),
        "--tolerance-rho-s-pct",
        "-3",
    ]);
    assert_eq!(code(&out), 2);
    assert!(
        stderr(&out).contains("--tolerance-rho-s-pct must be above 0"),
        "{}",
        stderr(&out)
    );
    // A paper the simulator does not know.
    let out = gonio(&[
        "batch",
        "--library",
        s(&library),
        "--master",
        "Stock-SG",
        "--sim",
        "GG",
        "--sheets",
        "2",
        "--out",
        s(&root.join("gg")),
    ]);
    assert_eq!(code(&out), 2);
    assert!(
        stderr(&out).contains("unknown sample 'GG'"),
        "{}",
        stderr(&out)
    );
    assert!(!root.join("gg").exists(), "nothing written");
    let _ = std::fs::remove_dir_all(&root);
}

/// batch.html: a self-contained page a browser renders, the sample's name escaped.
#[test]
fn the_batch_report_renders_in_a_headless_browser() {
    let Some(chromium) = crate::common::chromium_or_skip() else {
        return;
    };
    let seed = run_seed();
    let root = temp_dir("batch", "report");
    let library = library_with_master(&root, "Stock-SG", "SG", 1, seed);
    let dir = root.join("batch");
    let out = batch(
        &library,
        "Stock-SG",
        "G",
        "2",
        &dir,
        seed,
        &["--sample", "<b>A&'s</b>", "--spots", "1"],
    );
    assert_eq!(code(&out), 3, "{}", stderr(&out));
    let page = dir.join("batch.html");
    let html = std::fs::read_to_string(&page).expect("batch.html");
    assert!(
        !html.contains("<b>A&") && html.contains("&lt;b&gt;A&amp;"),
        "the sample name is escaped"
    );
    assert!(
        !html.contains("<script") && !html.contains("https://"),
        "self-contained"
    );
    let out = host::output::chromium::headless(&chromium, &page, &["--dump-dom".into()])
        .expect("chromium runs");
    let dom = String::from_utf8_lossy(&out.stdout);
    for wanted in [
        "QA batch of",
        "against the master stock Stock-SG",
        "Master stock and tolerances",
        "Statistics across the sheets",
        "individuals chart: σ",
        "fail: σ",
        "sheet-02",
    ] {
        assert!(dom.contains(wanted), "{wanted:?} not in the page");
    }
    assert!(
        dom.matches("<circle").count() >= 2,
        "the charts' points are drawn"
    );
    let _ = std::fs::remove_dir_all(&root);
}

/// A batch is one procedure: its plan records the policy it began with; sheets begun after
/// a resume are measured under it (before, a resume without `--policy` measured them
/// adaptive whatever the batch began with), and a resume giving another is refused by
/// name. The interruption is made by hand: a batch of one sheet, its plan then asking for
/// two and its status set back to interrupted.
#[test]
fn a_resumed_batch_keeps_the_policy_it_began_with() {
    let seed = run_seed();
    let root = temp_dir("batch", "policy");
    let library = library_with_master(&root, "Stock-PPC", "PPC", 1, seed);
    let dir = root.join("batch");
    let out = batch(
        &library,
        "Stock-PPC",
        "PPC",
        "1",
        &dir,
        seed,
        &["--policy", "paper", "--spots", "1"],
    );
    assert!(out.status.success() || code(&out) == 3, "{}", stderr(&out));
    let mut doc = batch_json(&dir);
    assert_eq!(doc["plan"]["policy"], "paper", "{}", doc["plan"]);
    doc["plan"]["sheets"] = 2.into();
    doc["status"] = "interrupted".into();
    std::fs::write(dir.join("batch.json"), doc.to_string()).unwrap();

    let resume = |extra: &[&str]| {
        let mut args = vec!["batch", "--library", s(&library), "--sim", "PPC"];
        args.extend_from_slice(extra);
        args.extend(["--resume", s(&dir)]);
        gonio(&args)
    };
    let refused = resume(&["--policy", "adaptive"]);
    assert_eq!(code(&refused), 1, "{}", stderr(&refused));
    assert!(
        stderr(&refused).contains("--policy adaptive differs from the batch's plan (policy paper)"),
        "{}",
        stderr(&refused)
    );
    let out = resume(&[]);
    assert!(out.status.success() || code(&out) == 3, "{}", stderr(&out));
    let session: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("sheet-02/session.json")).expect("sheet 2"))
            .unwrap();
    assert_eq!(session["plan"]["policy"], "paper", "{}", session["plan"]);
    let _ = std::fs::remove_dir_all(&root);
}

/// `gonio` with `XDG_DATA_HOME` in `root`: no profile installed there, whatever this
/// machine has installed in its own.
fn gonio_in(root: &Path, args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_gonio"))
        .args(args)
        .env("XDG_DATA_HOME", root.join("xdg"))
        .stdin(Stdio::null())
        .output()
        .expect("run gonio")
}

/// Whether a sheet of batch.json has a clean result (only informational flags).
fn clean(sheet: &serde_json::Value) -> bool {
    sheet["flags"].as_array().unwrap().iter().all(|f| {
        host::analysis::flags::Flag::ALL
            .iter()
            .any(|k| *f == k.name() && k.is_informational())
    })
}

/// The simulated instrument's profile, characterized into `root/instrument.json`.
pub(crate) fn simulated_profile(root: &Path, seed: u64) -> PathBuf {
    let profile = root.join("instrument.json");
    let out = gonio_in(
        root,
        &[
            "characterize",
            "--sim",
            "--seed",
            &seed.to_string(),
            "--rehomes",
            "1",
            "--lamp-s",
            "5",
            "--out",
            s(&profile),
        ],
    );
    assert!(out.status.success(), "characterize: {}", stderr(&out));
    profile
}

/// The analytic gloss of the simulator's paper `paper` at the geometry of `angle_deg`.
fn analytic_gloss(paper: &str, angle_deg: f64) -> f64 {
    let p = host::instrument::sim::sample_params(paper).expect("a paper");
    let g = host::analysis::gloss::GLOSS_GEOMETRIES
        .iter()
        .find(|g| g.angle_deg == angle_deg)
        .expect("a geometry");
    host::analysis::gloss::gloss_units(&p, g)
}

/// The gloss specification: each sheet measured with the instrument's profile has its
/// gloss judged against it beside σ, ρs and ρd. Against SG's own 60° gloss ± 5 GU it
/// passes; against a 20° specification 20 GU above SG's it fails, the verdict naming the
/// gloss, its value, the specification and how far beyond; at 85°, which the arms do not
/// reach, it is undecided and says so, named beside the failure. Without a profile every
/// sheet is undecided on gloss, with the reason, never a pass.
#[test]
fn gloss_is_judged_against_its_specification_and_undecided_without_a_profile() {
    let seed = run_seed();
    let root = temp_dir("batch", "gloss");
    std::fs::create_dir_all(&root).unwrap();
    let library = library_with_master(&root, "Stock-SG", "SG", 1, seed);
    let profile = simulated_profile(&root, seed);
    let (g20, g60) = (analytic_gloss("SG", 20.0), analytic_gloss("SG", 60.0));
    let passing = format!("60={g60:.1}±5");
    let failing = format!("20={:.1}+-3", g20 + 20.0);
    let dir = root.join("with-profile");
    let seed_text = seed.to_string();
    let args = |dir: &Path, specs: &[String], extra: &[&str]| {
        let mut args: Vec<String> = [
            "batch",
            "--library",
            s(&library),
            "--master",
            "Stock-SG",
            "--sim",
            "SG",
            "--sheets",
            "2",
            "--spots",
            "1",
            "--sheet-to-sheet-pct",
            "0",
            "--seed",
            &seed_text,
            "--out",
            s(dir),
        ]
        .map(String::from)
        .to_vec();
        for spec in specs {
            args.extend(["--gloss-spec".to_string(), spec.clone()]);
        }
        args.extend(extra.iter().map(|e| e.to_string()));
        args
    };
    let run = |args: Vec<String>| {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        gonio_in(&root, &args)
    };
    let out = run(args(
        &dir,
        &[passing.clone(), failing.clone(), "85=10±5".to_string()],
        &["--instrument", s(&profile)],
    ));
    assert_eq!(code(&out), 3, "{}", stderr(&out));
    let doc = batch_json(&dir);
    assert_eq!(doc["plan"]["gloss_spec"].as_array().unwrap().len(), 3);
    let mut judged = 0;
    for sheet in doc["sheets"].as_array().unwrap() {
        let j = sheet["gloss_judgements"].as_array().unwrap();
        assert_eq!(j.len(), 3, "{sheet}");
        if !clean(sheet) {
            // A flagged result is judged on nothing; it says so.
            assert!(j.iter().all(|j| j["verdict"] == "undecided"), "{sheet}");
            continue;
        }
        judged += 1;
        let gloss60 = j[0]["gloss_units"].as_f64().expect("gloss at 60°");
        assert!((gloss60 - g60).abs() < 2.0, "{gloss60} against {g60}");
        assert_eq!(j[0]["verdict"], "pass", "{sheet}");
        assert_eq!(j[1]["verdict"], "fail", "{sheet}");
        assert_eq!(j[2]["verdict"], "undecided", "{sheet}");
        assert!(
            j[2]["why"]
                .as_str()
                .unwrap()
                .contains("arms do not reach its receptor"),
            "{sheet}"
        );
        assert_eq!(sheet["verdict"], "fail", "{sheet}");
        let gloss20 = j[1]["gloss_units"].as_f64().unwrap();
        let beyond = j[1]["beyond_gloss_units"].as_f64().unwrap();
        // As the verdict writes the specification: the number given, without trailing zeros.
        let spec_target: f64 = format!("{:.1}", g20 + 20.0).parse().unwrap();
        let named =
            format!("gloss 20° {gloss20:.1} GU (spec {spec_target} ± 3, {beyond:.1} beyond)");
        let stdout = String::from_utf8_lossy(&out.stdout);
        assert!(stdout.contains(&named), "{named} in\n{stdout}");
        assert!(stdout.contains("not judged: gloss 85°"), "{stdout}");
        // The CSV carries the specification and the verdict per geometry.
        let csv = std::fs::read_to_string(dir.join("batch.csv")).unwrap();
        let header = csv.lines().next().unwrap();
        assert!(
            header.contains("gloss 20 deg spec (GU)") && header.contains("gloss 60 deg verdict"),
            "{header}"
        );
        assert!(csv.contains("gloss_20deg"), "{csv}");
    }
    assert!(judged >= 1, "no sheet with a clean result: {doc}");
    // The report shows the specification.
    let html = std::fs::read_to_string(dir.join("batch.html")).unwrap();
    assert!(
        html.contains("gloss specification")
            && html.contains("(--gloss-spec <code>60=")
            && html.contains("individuals chart: gloss 60°"),
        "{html}"
    );

    // Without a profile: undecided on gloss, with the reason; never a pass.
    let bare = root.join("no-profile");
    let out = run(args(&bare, std::slice::from_ref(&passing), &[]));
    assert_eq!(code(&out), 3, "{}", stderr(&out));
    let doc = batch_json(&bare);
    let sheets = doc["sheets"].as_array().unwrap();
    for sheet in sheets {
        assert_ne!(sheet["verdict"], "pass", "{sheet}");
        let j = &sheet["gloss_judgements"][0];
        assert_eq!(j["verdict"], "undecided", "{sheet}");
        assert!(sheet["gloss"].as_array().unwrap().is_empty(), "{sheet}");
        if clean(sheet) {
            assert!(
                j["why"]
                    .as_str()
                    .unwrap()
                    .contains("no instrument profile was in force"),
                "{sheet}"
            );
        }
    }
    if sheets.iter().any(clean) {
        let stdout = String::from_utf8_lossy(&out.stdout);
        assert!(
            stdout.contains("gloss 60°: no gloss: no instrument profile was in force"),
            "{stdout}"
        );
    }
    let _ = std::fs::remove_dir_all(&root);
}

/// A batch is judged against one gloss specification: a resume without `--gloss-spec`
/// keeps the batch's (its next sheet judged against it), one giving another is refused by
/// name before anything is measured. A `gonio-batch/2` batch.json (no gloss) is read and
/// written back as `gonio-batch/3` with none.
#[test]
fn a_resumed_batch_keeps_its_gloss_spec_and_refuses_another() {
    let seed = run_seed();
    let root = temp_dir("batch", "gloss-resume");
    let library = library_with_master(&root, "Stock-PPC", "PPC", 1, seed);
    let dir = root.join("batch");
    let out = batch(
        &library,
        "Stock-PPC",
        "PPC",
        "1",
        &dir,
        seed,
        &["--spots", "1", "--gloss-spec", "60=45±3"],
    );
    assert_eq!(code(&out), 3, "undecided on gloss: {}", stderr(&out));
    let mut doc = batch_json(&dir);
    let spec = doc["plan"]["gloss_spec"].clone();
    assert_eq!(spec[0]["target_gloss_units"], 45.0, "{spec}");
    doc["plan"]["sheets"] = 3.into();
    doc["status"] = "interrupted".into();
    std::fs::write(dir.join("batch.json"), doc.to_string()).unwrap();
    let resume = |extra: &[&str]| {
        let mut args = vec!["batch", "--library", s(&library), "--sim", "PPC"];
        args.extend_from_slice(extra);
        args.extend(["--resume", s(&dir)]);
        gonio(&args)
    };
    let before = std::fs::read(dir.join("batch.json")).unwrap();
    let refused = resume(&["--gloss-spec", "60=40±3"]);
    assert_eq!(code(&refused), 1, "{}", stderr(&refused));
    assert!(
        stderr(&refused)
            .contains("--gloss-spec 60=40±3 differs from the batch's plan (gloss spec 60=45±3)"),
        "{}",
        stderr(&refused)
    );
    assert_eq!(std::fs::read(dir.join("batch.json")).unwrap(), before);
    assert!(!dir.join("sheet-02").exists(), "nothing measured");
    // The same specification again is the batch's own: accepted.
    let out = resume(&["--gloss-spec", "60°=45+-3"]);
    assert_eq!(code(&out), 3, "{}", stderr(&out));
    let doc = batch_json(&dir);
    assert_eq!(doc["plan"]["gloss_spec"], spec);
    assert_eq!(doc["sheets"].as_array().unwrap().len(), 3);
    for sheet in doc["sheets"].as_array().unwrap() {
        assert_eq!(
            sheet["gloss_judgements"][0]["verdict"], "undecided",
            "{sheet}"
        );
    }

    // gonio-batch/2: no gloss specification, no sheet's gloss; resumed, written as /3.
    let mut old = doc.clone();
    old["schema"] = "gonio-batch/2".into();
    old["status"] = "interrupted".into();
    old["plan"]["sheets"] = 4.into();
    let plan = old["plan"].as_object_mut().unwrap();
    plan.remove("gloss_spec");
    plan.remove("instrument_profile");
    for sheet in old["sheets"].as_array_mut().unwrap() {
        let sheet = sheet.as_object_mut().unwrap();
        sheet.remove("gloss");
        sheet.remove("gloss_judgements");
        if sheet["verdict"] == "fail" {
            sheet.remove("gloss_exceeded");
            sheet.remove("undecided");
        }
    }
    std::fs::write(dir.join("batch.json"), old.to_string()).unwrap();
    let out = resume(&[]);
    assert!(matches!(code(&out), 0 | 3), "{}", stderr(&out));
    let doc = batch_json(&dir);
    assert_eq!(doc["schema"], "gonio-batch/3");
    assert_eq!(doc["plan"]["gloss_spec"], serde_json::json!([]));
    assert_eq!(doc["sheets"][3]["gloss_judgements"], serde_json::json!([]));
    let _ = std::fs::remove_dir_all(&root);
}

/// A gloss specification that is not one is refused by clap's usage code, naming the
/// option and the value, before any library is read or folder made; so is one geometry
/// specified twice.
#[test]
fn a_bad_gloss_spec_is_refused_before_anything_is_measured() {
    let root = temp_dir("batch", "gloss-bad");
    std::fs::create_dir_all(&root).unwrap();
    let out_dir = root.join("out");
    let run = |specs: &[&str]| {
        let mut args = vec![
            "batch",
            "--library",
            "no-such-library.sqlite",
            "--master",
            "Stock-SG",
            "--sim",
            "SG",
            "--sheets",
            "2",
            "--out",
            s(&out_dir),
        ];
        for spec in specs {
            args.extend(["--gloss-spec", spec]);
        }
        gonio(&args)
    };
    for (spec, says) in [
        ("60=45", "gives no tolerance"),
        ("45=10±1", "'45' is not a gloss geometry gonio computes"),
        ("60=45±0", "the tolerance '0'"),
        ("60", "is not GEOMETRY=TARGET±TOLERANCE"),
    ] {
        let out = run(&[spec]);
        assert_eq!(code(&out), 2, "{spec}: {}", stderr(&out));
        let err = stderr(&out);
        assert!(
            err.contains("--gloss-spec") && err.contains(spec) && err.contains(says),
            "{spec}: {err}"
        );
        assert!(!out_dir.exists(), "{spec}: nothing written");
    }
    let out = run(&["60=45±3", "60°=40+-2"]);
    assert_eq!(code(&out), 2, "{}", stderr(&out));
    assert!(
        stderr(&out)
            .contains("--gloss-spec 60=45±3 and --gloss-spec 60=40±2: gloss 60° specified twice"),
        "{}",
        stderr(&out)
    );
    assert!(!out_dir.exists(), "nothing written");
    let _ = std::fs::remove_dir_all(&root);
}

/// One batch, one process: while a gonio batch holds the batch folder, a second one on
/// it, resuming it or beginning a new batch there, is refused naming the folder and the
/// holder, and nothing of the first is changed; once it lets go, the batch resumes. The
/// holder is taken here through the same lock a running gonio batch takes (deterministic:
/// no race with a batch that might finish first).
#[test]
fn a_second_batch_on_a_folder_in_use_is_refused_naming_the_holder() {
    let seed = run_seed();
    let root = temp_dir("batch", "lock");
    let library = library_with_master(&root, "Stock-PPC", "PPC", 1, seed);
    let dir = root.join("batch");
    let out = batch(
        &library,
        "Stock-PPC",
        "PPC",
        "1",
        &dir,
        seed,
        &["--spots", "1"],
    );
    assert!(matches!(code(&out), 0 | 3), "{}", stderr(&out));
    assert!(!dir.join("batch.lock").exists(), "let go at the end");
    let mut doc = batch_json(&dir);
    doc["plan"]["sheets"] = 2.into();
    doc["status"] = "interrupted".into();
    std::fs::write(dir.join("batch.json"), doc.to_string()).unwrap();
    let before = std::fs::read(dir.join("batch.json")).unwrap();
    let sheet_before = std::fs::read(dir.join("sheet-01/session.json"))
        .or_else(|_| std::fs::read(dir.join("sheet-01/sheet.json")))
        .unwrap();

    let mut holder = host::output::batch::BatchLock::take(&dir).expect("the folder is free");
    holder.announce().unwrap();
    let pid = format!("process {}", std::process::id());
    let resume = || gonio(&["batch", "--sim", "PPC", "--resume", s(&dir)]);
    let refused = resume();
    assert_eq!(code(&refused), 1, "{}", stderr(&refused));
    let err = stderr(&refused);
    assert!(
        err.contains(&format!(
            "{} is in use by another gonio batch",
            dir.display()
        )) && err.contains(&pid),
        "{err}"
    );
    assert_eq!(std::fs::read(dir.join("batch.json")).unwrap(), before);
    assert!(!dir.join("sheet-02").exists(), "nothing measured");
    // A new batch onto the folder in use: the same.
    let empty = root.join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let mut other = host::output::batch::BatchLock::take(&empty).unwrap();
    other.announce().unwrap();
    let out = batch(
        &library,
        "Stock-PPC",
        "PPC",
        "1",
        &empty,
        seed,
        &["--spots", "1"],
    );
    assert_eq!(code(&out), 1, "{}", stderr(&out));
    assert!(
        stderr(&out).contains(&format!(
            "{} is in use by another gonio batch",
            empty.display()
        )) && stderr(&out).contains(&pid),
        "{}",
        stderr(&out)
    );
    assert!(!empty.join("batch.json").exists());
    drop(other);
    drop(holder);

    // Let go: the batch resumes, its first sheet as it was.
    let out = resume();
    assert!(matches!(code(&out), 0 | 3), "{}", stderr(&out));
    let doc = batch_json(&dir);
    assert_eq!(doc["status"], "finished");
    assert_eq!(doc["sheets"].as_array().unwrap().len(), 2);
    let sheet_after = std::fs::read(dir.join("sheet-01/session.json"))
        .or_else(|_| std::fs::read(dir.join("sheet-01/sheet.json")))
        .unwrap();
    assert_eq!(sheet_after, sheet_before);
    let _ = std::fs::remove_dir_all(&root);
}
