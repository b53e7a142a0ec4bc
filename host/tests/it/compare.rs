//! `gonio compare`: same stock or not, from two session.json files — identical sheets,
//! sheets far apart, different classes, parameters not determined, and bad inputs.
use host::analysis::compare::{self, CompareError};
use host::analysis::evidence;
use serde_json::{Value, json};
use std::path::{Path, PathBuf};
use std::process::Command;

/// `gonio` with a user library directory of its own: nothing on this machine chooses the
/// population (the command line must).
fn gonio() -> Command {
    let mut command = Command::new(env!("CARGO_BIN_EXE_gonio"));
    command.env(
        "XDG_DATA_HOME",
        std::env::temp_dir().join(format!("gonio-compare-no-library-{}", std::process::id())),
    );
    command
}

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("gonio-compare-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir
}

/// Standard uncertainties of a glossy sheet's (σ, ρs, ρd, η), with a ρs–η correlation as
/// the fit gives it (both scale the peak).
const U_GLOSSY: [f64; 4] = [0.02, 1.0, 0.005, 0.01];

fn covariance(u: [f64; 4], rho_s_eta: f64) -> Vec<Vec<f64>> {
    let mut c = vec![vec![0.0; 4]; 4];
    for i in 0..4 {
        c[i][i] = u[i] * u[i];
    }
    c[1][3] = rho_s_eta * u[1] * u[3];
    c[3][1] = c[1][3];
    c
}

fn session(sample: &str, values: [Option<f64>; 4], class: &str, cov: Vec<Vec<f64>>) -> Value {
    json!({
        "sample": sample,
        "device": {"name": "sim"},
        "readings": [],
        "result": {
            "sample": sample,
            "sigma_deg": values[0], "rho_s": values[1], "rho_d": values[2], "eta": values[3],
            "class": class,
            "covariance": cov,
            "nmae": 0.01,
        }
    })
}

/// Write a session folder `dir/name/session.json` and return the folder.
fn write_session(dir: &Path, name: &str, value: &Value) -> PathBuf {
    let folder = dir.join(name);
    std::fs::create_dir_all(&folder).expect("folder");
    std::fs::write(
        folder.join("session.json"),
        serde_json::to_vec_pretty(value).expect("json"),
    )
    .expect("write");
    folder
}

fn glossy(sample: &str, sigma: f64, rho_s: f64, rho_d: f64, eta: f64) -> Value {
    session(
        sample,
        [Some(sigma), Some(rho_s), Some(rho_d), Some(eta)],
        "G",
        covariance(U_GLOSSY, -0.6),
    )
}

/// `gonio compare --json --demo-population`: the object and the exit code (0 computed, 3
/// computed with warnings: the demonstration population always warns).
fn run_json(a: &Path, b: &Path, extra: &[&str]) -> (Value, i32) {
    let out = gonio()
        .arg("compare")
        .arg("--json")
        .arg("--demo-population")
        .args(extra)
        .arg(a)
        .arg(b)
        .output()
        .expect("run gonio");
    let code = out.status.code().expect("an exit code");
    assert!(
        [0, 3].contains(&code),
        "exit {code}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    (
        serde_json::from_slice(&out.stdout).expect("one JSON object"),
        code,
    )
}

#[test]
fn identical_sheets_support_the_same_stock() {
    let dir = temp_dir("identical");
    let a = write_session(&dir, "a", &glossy("sheet-1", 0.8, 57.8, 0.855, 1.19));
    let b = write_session(&dir, "b", &glossy("sheet-2", 0.8, 57.8, 0.855, 1.19));
    let (v, code) = run_json(&a, &b, &[]);
    assert_eq!(code, 3, "the demonstration population warns: {v}");
    assert!(v["log10_lr"].as_f64().unwrap() > 1.0, "{v}");
    assert_eq!(v["support"], "same-stock");
    let kinds: Vec<&str> = v["warnings"]
        .as_array()
        .unwrap()
        .iter()
        .map(|w| w["kind"].as_str().unwrap())
        .collect();
    assert!(
        kinds.contains(&"demonstration") && kinds.contains(&"same-measurement"),
        "the same readings on both sides are said: {kinds:?}"
    );
    assert_eq!(v["population"]["label"], "for demonstration, not evidence");
    let (lo, hi) = (
        v["bounds"][0].as_f64().unwrap(),
        v["bounds"][1].as_f64().unwrap(),
    );
    let reported = v["log10_lr"].as_f64().unwrap();
    assert!(lo <= reported && reported <= hi, "{v}");
    assert!(
        v["verbal"]
            .as_str()
            .unwrap()
            .contains("support for the same stock"),
        "{v}"
    );
    assert_eq!(v["population"]["source"]["kind"], "demonstration");
    assert_eq!(v["n_spots"], serde_json::json!([1, 1]));
    assert_eq!(
        v["parameters"],
        serde_json::json!(["sigma_deg", "rho_s", "rho_d"])
    );
    assert_eq!(
        (v["a"]["class"].as_str(), v["b"]["class"].as_str()),
        (Some("G"), Some("G"))
    );
    // The report says so too, with labelled intervals; a session.json path works as well as its folder.
    let out = gonio()
        .arg("compare")
        .arg("--demo-population")
        .arg(&a)
        .arg(b.join("session.json"))
        .output()
        .expect("run gonio");
    let table = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(3), "{table}");
    assert!(
        table.contains("95 % interval")
            && table.contains("likelihood ratio")
            && table.contains("population: the demonstration population")
            && table.contains("FOR DEMONSTRATION, NOT EVIDENCE"),
        "{table}"
    );
    assert!(
        table.contains("within-sheet variation is unknown"),
        "one spot each: said: {table}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_library_too_small_for_a_population_says_so_and_the_default_is_used() {
    let dir = temp_dir("library");
    let a = write_session(&dir, "a", &glossy("a", 0.8, 57.8, 0.855, 1.19));
    let b = write_session(&dir, "b", &glossy("b", 0.8, 57.8, 0.855, 1.19));
    let missing = dir.join("no-such-library.sqlite");
    let out = gonio()
        .arg("compare")
        .arg("--library")
        .arg(&missing)
        .arg(&a)
        .arg(&b)
        .output()
        .expect("run gonio");
    assert_eq!(
        out.status.code(),
        Some(1),
        "a library that is not there is an error"
    );
    assert!(!missing.exists(), "and is not created");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn sheets_far_apart_support_different_stocks() {
    let dir = temp_dir("far");
    let a = write_session(&dir, "a", &glossy("a", 0.8, 57.8, 0.855, 1.19));
    // ρd 50 % higher: far beyond the demonstration's 3 % between spots and 3 % between
    // sheets (one spot each: about 6 % apart is the spread of two sheets of one stock).
    let b = write_session(&dir, "b", &glossy("b", 0.8, 57.8, 0.855 * 1.5, 1.19));
    let (v, code) = run_json(&a, &b, &[]);
    assert_eq!(code, 3, "{v}");
    assert!(v["log10_lr"].as_f64().unwrap() < -1.0, "{v}");
    assert_eq!(v["support"], "different-stocks");
    // ρd carries it: its contribution is the most negative.
    let contributions = v["contributions"].as_array().unwrap();
    let worst = contributions
        .iter()
        .min_by(|x, y| {
            x["log10_lr"]
                .as_f64()
                .unwrap()
                .total_cmp(&y["log10_lr"].as_f64().unwrap())
        })
        .unwrap();
    assert_eq!(worst["parameter"], "rho_d", "{v}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn one_standard_error_apart_supports_the_same_stock() {
    let a = compare::parse_session(
        Path::new("a.json"),
        &glossy("a", 0.8, 57.8, 0.855, 1.19).to_string(),
    )
    .expect("parse");
    let b = compare::parse_session(
        Path::new("b.json"),
        &glossy("b", 0.82, 58.8, 0.86, 1.2).to_string(),
    )
    .expect("parse");
    let e = evidence::weigh(
        &evidence::Questioned::of(a.sheet()),
        &evidence::Questioned::of(b.sheet()),
        &evidence::Population::demonstration(),
    );
    assert!(
        e.ratio.log10_lr > 1.0 && e.ratio.support == evidence::Support::SameStock,
        "{e:?}"
    );
    assert_eq!(
        e.parameters,
        ["sigma_deg", "rho_s", "rho_d"],
        "η is not weighed"
    );
}

/// A session whose fit tested the model's extensions: its covariance holds the `model form`
/// widening (the budget's two terms of that kind), which the evidence weighs as the square
/// of how far the fit's terms moved the estimate from the paper's model's (recorded, or 0
/// where a record from before it added no term), and whole where that is not known; the
/// spot as reported keeps it either way.
#[test]
fn the_evidence_weighs_the_shift_from_the_papers_model_in_place_of_the_model_form() {
    // σ's variance: 0.02² from the noise, 0.2² and 0.1² from the two model-form terms.
    let (noise, union, outside) = (0.02_f64.powi(2), 0.2_f64.powi(2), 0.1_f64.powi(2));
    let whole = noise + union + outside;
    let with = |extension: Option<Value>| {
        let mut u = U_GLOSSY;
        u[0] = whole.sqrt();
        let mut doc = glossy("a", 21.7, 0.409, 0.414, 3.0);
        doc["result"]["covariance"] = json!(covariance(u, -0.6));
        doc["result"]["budget"] = json!({"terms": [
            {"name": "reading noise", "kind": "reading noise",
             "variance": {"sigma_deg": noise, "rho_s": 1.0, "rho_d": 2.5e-5}},
            {"name": "model form", "kind": "model form",
             "variance": {"sigma_deg": union, "rho_s": 0.0, "rho_d": 0.0}},
            {"name": "model form: shapes outside the family", "kind": "model form",
             "variance": {"sigma_deg": outside, "rho_s": 0.0, "rho_d": 0.0}},
        ]});
        if let Some(extension) = extension {
            doc["result"]["model_extension"] = extension;
        }
        compare::parse_session(Path::new("a.json"), &doc.to_string()).expect("parse")
    };
    let sigma_var = |r: &compare::SessionResult| r.weighed_spot().covariance[0][0];
    let shift = |sigma: Value| json!({"sigma_deg": sigma, "rho_s": 0.0, "rho_d": 0.0});
    let haze =
        json!([{"name": "haze lobe", "description": "", "statistic": 20.0, "critical": 11.6}]);
    let cases = [
        // No term added, the shift recorded (0), or from before it was (terms empty).
        (
            json!({"terms": [], "tests": [], "plausible": [], "shift_from_paper_model": shift(json!(0.0))}),
            noise,
        ),
        (json!({"terms": [], "tests": [], "plausible": []}), noise),
        // A term added that moved σ 0.15° from the paper's model.
        (
            json!({"terms": haze, "tests": [], "plausible": [], "shift_from_paper_model": shift(json!(-0.15))}),
            noise + 0.0225,
        ),
        // Not known: a term added before the shift was recorded, σ's shift null, a record
        // that cannot be read, or no extension step at all.
        (json!({"terms": haze, "tests": [], "plausible": []}), whole),
        (
            json!({"terms": [], "tests": [], "plausible": [], "shift_from_paper_model": shift(Value::Null)}),
            whole,
        ),
        (json!("not an object"), whole),
    ];
    for (extension, expected) in cases {
        let r = with(Some(extension.clone()));
        assert!(
            (sigma_var(&r) - expected).abs() < 1e-12,
            "{extension}: {:?}",
            r.weighed_spot()
        );
        assert!(
            (r.spot().covariance[0][0] - whole).abs() < 1e-12,
            "reported as is"
        );
        assert_eq!(r.sheet().spots, vec![r.weighed_spot()]);
        // ρs and ρd: no model-form variance and no shift, nothing changed.
        assert_eq!(r.weighed_spot().covariance[1], r.spot().covariance[1]);
    }
    assert!((sigma_var(&with(None)) - whole).abs() < 1e-12);

    // `gonio compare` weighs the shift but shows each sheet's interval as its session
    // reported it, the widening in it.
    let dir = temp_dir("shift");
    let mut doc = glossy("a", 21.7, 0.409, 0.414, 3.0);
    let mut u = U_GLOSSY;
    u[0] = whole.sqrt();
    doc["result"]["covariance"] = json!(covariance(u, -0.6));
    doc["result"]["budget"] = json!({"terms": [
        {"name": "model form", "kind": "model form",
         "variance": {"sigma_deg": union + outside, "rho_s": 0.0, "rho_d": 0.0}},
    ]});
    doc["result"]["model_extension"] = json!({"terms": [], "tests": [], "plausible": []});
    let a = write_session(&dir, "a", &doc);
    let b = write_session(&dir, "b", &doc);
    let (v, _) = run_json(&a, &b, &[]);
    for side in ["a", "b"] {
        let (lo, hi) = (
            v[side]["ci95"]["sigma_deg"][0].as_f64().unwrap(),
            v[side]["ci95"]["sigma_deg"][1].as_f64().unwrap(),
        );
        assert!(
            ((hi - lo) / 2.0 - 1.96 * whole.sqrt()).abs() < 1e-9,
            "{side}: [{lo}, {hi}] against ± {}",
            1.96 * whole.sqrt()
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_class_boundary_between_two_sheets_is_not_evidence_of_different_stocks() {
    let dir = temp_dir("classes");
    let a = write_session(
        &dir,
        "a",
        &session(
            "a",
            [Some(21.7), Some(0.409), Some(0.414), Some(3.0)],
            "rough-II",
            covariance([0.05, 0.002, 0.001, 0.0], 0.0),
        ),
    );
    // Same numbers, other class (as a sheet right at a group boundary could get).
    let b = write_session(
        &dir,
        "b",
        &session(
            "b",
            [Some(21.7), Some(0.409), Some(0.414), Some(3.0)],
            "rough-I",
            covariance([0.05, 0.002, 0.001, 0.0], 0.0),
        ),
    );
    let (v, code) = run_json(&a, &b, &[]);
    assert_eq!(
        code, 3,
        "the parameters agree (the demonstration warns): {v}"
    );
    assert!(v["log10_lr"].as_f64().unwrap() > 1.0, "{v}");
    assert_eq!(
        (v["a"]["class"].as_str(), v["b"]["class"].as_str()),
        (Some("rough-II"), Some("rough-I"))
    );
    let out = gonio()
        .arg("compare")
        .arg("--demo-population")
        .arg(&a)
        .arg(&b)
        .output()
        .expect("run gonio");
    let table = String::from_utf8_lossy(&out.stdout);
    assert!(table.contains("not the class boundaries"), "{table}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn unresolved_sigma_is_left_out() {
    let a = session(
        "a",
        [None, Some(57.0), Some(0.8), Some(1.1)],
        "G",
        covariance([0.0, 1.0, 0.005, 0.01], 0.0),
    );
    let b = glossy("b", 0.8, 57.8, 0.855, 1.19);
    let a = compare::parse_session(Path::new("a"), &a.to_string()).expect("null σ is allowed");
    let b = compare::parse_session(Path::new("b"), &b.to_string()).expect("parse");
    let e = evidence::weigh(
        &evidence::Questioned::of(a.sheet()),
        &evidence::Questioned::of(b.sheet()),
        &evidence::Population::demonstration(),
    );
    assert_eq!(e.parameters, ["rho_s", "rho_d"]);
    assert_eq!(e.left_out, [("sigma_deg", "not determined by A")]);
    assert!(e.ratio.log10_lr.is_finite());
}

#[test]
fn bad_inputs_name_the_file_and_the_key() {
    let dir = temp_dir("bad");
    let good = write_session(&dir, "good", &glossy("good", 0.8, 57.8, 0.855, 1.19));

    let missing = dir.join("nowhere");
    match compare::read_session(&missing) {
        Err(CompareError::Io { path, .. }) => assert_eq!(path, missing),
        other => panic!("{other:?}"),
    }

    let broken = dir.join("broken.json");
    std::fs::write(&broken, "{\"sample\": ").expect("write");
    let e = compare::read_session(&broken).expect_err("not JSON");
    assert!(
        matches!(e, CompareError::Json { .. }) && e.to_string().contains("broken.json"),
        "{e}"
    );

    let mut no_cov = glossy("x", 0.8, 57.8, 0.855, 1.19);
    no_cov["result"]
        .as_object_mut()
        .unwrap()
        .remove("covariance");
    let no_cov = write_session(&dir, "no-cov", &no_cov);
    let e = compare::read_session(&no_cov).expect_err("no covariance");
    assert!(
        e.to_string().contains("no-cov/session.json")
            && e.to_string().contains("`result.covariance`"),
        "{e}"
    );

    let mut short_cov = glossy("x", 0.8, 57.8, 0.855, 1.19);
    short_cov["result"]["covariance"] = json!([[1.0, 0.0], [0.0, 1.0]]);
    let e = compare::parse_session(Path::new("s.json"), &short_cov.to_string()).expect_err("2×2");
    assert!(e.to_string().contains("4×4"), "{e}");

    let mut text_rho = glossy("x", 0.8, 57.8, 0.855, 1.19);
    text_rho["result"]["rho_d"] = json!("0.8");
    let e =
        compare::parse_session(Path::new("s.json"), &text_rho.to_string()).expect_err("string ρd");
    assert!(e.to_string().contains("`result.rho_d`"), "{e}");

    let e = compare::parse_session(Path::new("s.json"), "{\"result\": {}}").expect_err("no sample");
    assert!(e.to_string().contains("`sample`"), "{e}");

    // The command line: exit 1 (an error, apart from 0 and 3 for a ratio computed), the
    // file and key on stderr.
    let out = gonio()
        .arg("compare")
        .arg("--demo-population")
        .arg(&good)
        .arg(&no_cov)
        .output()
        .expect("run gonio");
    assert_eq!(out.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("no-cov") && stderr.contains("result.covariance"),
        "{stderr}"
    );
    let out = gonio()
        .args(["compare", "--no-such-option"])
        .arg(&good)
        .arg(&good)
        .output()
        .expect("run gonio");
    assert_eq!(out.status.code(), Some(2), "a wrong command line");
    // No population named: refused, never chosen by a file's presence.
    let out = gonio()
        .arg("compare")
        .arg(&good)
        .arg(&good)
        .output()
        .expect("run gonio");
    assert_eq!(out.status.code(), Some(2), "no population named");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("--library") && stderr.contains("--demo-population"),
        "{stderr}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// The `result` object a session writes for readings: the report's JSON plus the
/// covariance (as `gonio measure` adds it).
fn session_of(sample: &str, observations: Vec<host::analysis::fit::Observation>) -> Value {
    use host::analysis::{fit::FitOptions, result as analysis};
    let lines: Vec<usize> = (2..2 + observations.len()).collect();
    let readings = analysis::Readings {
        source: "x.csv",
        sample,
        observations: &observations,
        lines: &lines,
    };
    let r = analysis::analyse(&readings, &FitOptions::default(), None).expect("valid");
    let mut result = analysis::to_json(&r);
    result["covariance"] = json!(r.fit.covariance);
    json!({ "sample": sample, "result": result })
}

/// What a session did not determine is never compared: a sheet whose ρs the fit could not
/// identify (σ = 10°, ρs = 5, η = 1.001: only ρs·(η²−1) is fixed, class undecided) is
/// compared with another over σ and ρd only, and its undecided class does not make it a
/// "different class".
#[test]
fn undetermined_parameters_and_classes_are_not_compared() {
    let p = host::analysis::model::Params {
        sigma_deg: 10.0,
        rho_s: 5.0,
        rho_d: 0.5,
        eta: 1.001,
    };
    let geometries: Vec<(f64, f64)> = protocol::schedules::full_grid()
        .iter()
        .map(|g| (g.theta_i.deg(), g.theta_r.deg()))
        .collect();
    let reading = |seed: u64| -> Vec<host::analysis::fit::Observation> {
        // Deterministic small noise: a hash of the seed and the index, ±0.5 %.
        geometries
            .iter()
            .enumerate()
            .map(|(k, &(ti, tr))| {
                let f = host::analysis::model::observed_radiance_factor(&p, ti, tr, 1.0);
                let u = ((k as u64 * 2_654_435_761 + seed * 40_503) % 1000) as f64 / 1000.0 - 0.5;
                host::analysis::fit::Observation {
                    theta_i_deg: ti,
                    theta_r_deg: tr,
                    radiance_factor: f * (1.0 + 0.01 * u),
                    std: Some(0.003 * f + 0.001),
                    theta_r_span_deg: 0.0,
                }
            })
            .collect()
    };
    let a = session_of("a", reading(1));
    let b = session_of("b", reading(2));
    assert!(
        a["result"]["rho_s"].is_null() && a["result"]["class"].is_null(),
        "{}",
        a["result"]
    );
    let a = compare::parse_session(Path::new("a"), &a.to_string())
        .expect("null ρs and class are allowed");
    let b = compare::parse_session(Path::new("b"), &b.to_string()).expect("parse");
    assert_eq!(a.class, None);
    let population = evidence::Population::demonstration();
    let e = evidence::weigh(
        &evidence::Questioned::of(a.sheet()),
        &evidence::Questioned::of(b.sheet()),
        &population,
    );
    assert_eq!(
        e.left_out,
        [("rho_s", "determined by neither sheet")],
        "{e:?}"
    );
    assert_eq!(e.parameters, ["sigma_deg", "rho_d"]);
    assert!(
        e.ratio.log10_lr > 0.0,
        "the same sheet measured twice: {e:?}"
    );
}

/// `gonio compare --report FILE`: a self-contained page a browser renders, with the
/// propositions, the bounded ratio, every warning, the population and the audit trail;
/// text from the files goes in escaped.
#[test]
fn the_compare_report_renders_in_a_headless_browser_with_its_warnings() {
    let Some(chromium) = crate::common::chromium_or_skip() else {
        return;
    };
    let dir = temp_dir("report");
    let a = write_session(&dir, "a", &glossy("<b>A&'s</b>", 0.8, 57.8, 0.855, 1.19));
    let b = write_session(&dir, "b", &glossy("b", 0.81, 58.0, 0.86, 1.19));
    let page = dir.join("compare.html");
    let out = gonio()
        .args(["compare", "--demo-population", "--report"])
        .arg(&page)
        .arg(&a)
        .arg(&b)
        .output()
        .expect("run gonio");
    assert_eq!(
        out.status.code(),
        Some(3),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let html = std::fs::read_to_string(&page).expect("the report");
    assert!(
        !html.contains("<b>A&") && html.contains("&lt;b&gt;A&amp;"),
        "the sample name is escaped"
    );
    assert!(
        !html.contains("<script") && !html.contains("http://") && !html.contains("https://"),
        "self-contained: no script, nothing fetched"
    );
    let out = host::output::chromium::headless(&chromium, &page, &["--dump-dom".into()])
        .expect("chromium runs");
    let dom = String::from_utf8_lossy(&out.stdout);
    for wanted in [
        "Comparison of two sheets",
        "FOR DEMONSTRATION, NOT EVIDENCE",
        "Hp: the two sheets come from one paper stock",
        "Hd: the two sheets come from different stocks",
        "empirical bounds (ELUB)",
        "for demonstration, not evidence",
        "Audit trail",
        "population identity",
    ] {
        assert!(dom.contains(wanted), "{wanted:?} not in the page");
    }
    assert!(
        dom.matches("<li>").count() >= 3,
        "the propositions and at least one warning are listed"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// A lab's library (an exchange file of twelve stocks, three sheets of three spots each,
/// drawn anew on every run): `gonio forensic --library` validates it and records the
/// validation; `compare --library` then weighs against that population without a "not
/// validated" warning, within its bounds — and warns again once the library has changed.
#[test]
fn a_library_validated_by_forensic_is_what_compare_weighs_against() {
    use rand::SeedableRng;
    use rand_distr::{Distribution, StandardNormal};
    let seed = crate::common::run_seed();
    let mut rng = rand_chacha::ChaCha12Rng::seed_from_u64(seed);
    let mut normal = move || -> f64 { StandardNormal.sample(&mut rng) };
    let dir = temp_dir("validated");
    let kinds = [[0.8, 57.8, 0.855], [21.7, 0.409, 0.414], [11.0, 0.9, 0.6]];
    let mut lines = String::new();
    let mut record = |stock: usize, sheet: usize, values: [[f64; 3]; 3], sha: String| {
        for (spot, v) in values.iter().enumerate() {
            let cov: Vec<Vec<f64>> = (0..3)
                .map(|r| {
                    (0..3)
                        .map(|c| if r == c { (v[r] * 0.003).powi(2) } else { 0.0 })
                        .collect()
                })
                .collect();
            lines += &json!({
                "schema": "gonio-library/2", "stock": format!("S{stock:02}"),
                "manufacturer": null, "stock_notes": null, "session_sha256": sha,
                "sample": format!("S{stock:02}-{sheet}"), "lot": null, "measured_at": null,
                "instrument_serial": "SIM-0001", "session_path": format!("s{stock}-{sheet}"),
                "added_at": "2026-12-03T00:00:00.000Z", "spot": spot, "spots": 3,
                "sigma_deg": v[0], "rho_s": v[1], "rho_d": v[2], "covariance": cov,
            })
            .to_string();
            lines.push('\n');
        }
        let _ = sheet;
    };
    let mut stocks = Vec::new();
    for stock in 0..12 {
        let kind = kinds[stock % 3];
        let mean: [f64; 3] = std::array::from_fn(|i| kind[i] * (0.12 * normal()).exp());
        stocks.push(mean);
        for sheet in 0..3 {
            let sheet_mean: [f64; 3] = std::array::from_fn(|i| mean[i] * (0.02 * normal()).exp());
            let values: [[f64; 3]; 3] = std::array::from_fn(|_| {
                std::array::from_fn(|i| sheet_mean[i] * (0.02 * normal()).exp())
            });
            record(
                stock,
                sheet,
                values,
                format!("{:064x}", stock * 10 + sheet + 1),
            );
        }
    }
    let exchange = dir.join("library.jsonl");
    std::fs::write(&exchange, &lines).expect("write");
    let library = dir.join("library.sqlite");
    import(&library, &exchange);
    // Two questioned sheets of stock 4, as session results.
    let questioned = |name: &str| {
        let v: [f64; 3] = std::array::from_fn(|i| stocks[4][i] * (0.02 * normal_at(name, i)).exp());
        write_session(
            &dir,
            name,
            &session(
                name,
                [Some(v[0]), Some(v[1]), Some(v[2]), Some(1.5)],
                "rough-II",
                covariance([0.003 * v[0], 0.003 * v[1], 0.003 * v[2], 0.01], 0.0),
            ),
        )
    };
    let (a, b) = (questioned("qa"), questioned("qb"));
    let compare = || {
        let out = gonio()
            .args(["compare", "--json", "--library"])
            .arg(&library)
            .arg(&a)
            .arg(&b)
            .output()
            .expect("run gonio");
        let code = out.status.code();
        let v: Value = serde_json::from_slice(&out.stdout)
            .unwrap_or_else(|_| panic!("{}", String::from_utf8_lossy(&out.stderr)));
        (v, code)
    };
    let kinds_of = |v: &Value| -> Vec<String> {
        v["warnings"]
            .as_array()
            .unwrap()
            .iter()
            .map(|w| w["kind"].as_str().unwrap().to_string())
            .collect()
    };
    let (before, code) = compare();
    assert_eq!(code, Some(3), "{before}");
    assert!(
        kinds_of(&before).contains(&"not-validated".to_string()),
        "{before}"
    );
    let report = dir.join("validation");
    let out = gonio()
        .args(["forensic", "--library"])
        .arg(&library)
        .arg("--out")
        .arg(&report)
        .output()
        .expect("run gonio");
    assert!(
        out.status.success(),
        "seed {seed}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    for file in ["summary.md", "tippett.svg", "ece.svg"] {
        assert!(report.join(file).is_file(), "{file}");
    }
    let summary = std::fs::read_to_string(report.join("summary.md")).unwrap();
    assert!(
        summary.contains("ELUB bounds") && summary.contains("Cllr_cal"),
        "{summary}"
    );
    let (after, _) = compare();
    assert!(
        !kinds_of(&after).contains(&"not-validated".to_string()),
        "seed {seed}: {after}"
    );
    assert_eq!(
        after["population"]["identity"],
        before["population"]["identity"]
    );
    let (lo, hi) = (
        after["bounds"][0].as_f64().unwrap(),
        after["bounds"][1].as_f64().unwrap(),
    );
    let reported = after["log10_lr"].as_f64().unwrap();
    assert!(
        lo <= reported && reported <= hi && lo < 0.0 && hi > 0.0,
        "{after}"
    );
    assert!(
        reported > 0.0,
        "seed {seed}: two sheets of one stock: {after}"
    );
    // A sheet added: the library's population is another, not the one validated.
    let mut more = String::new();
    for line in lines.lines().take(3) {
        more += &line.replace(&format!("{:064x}", 1), &format!("{:064x}", 999));
        more.push('\n');
    }
    std::fs::write(&exchange, more).unwrap();
    import(&library, &exchange);
    let (changed, _) = compare();
    assert!(
        kinds_of(&changed).contains(&"not-validated".to_string()),
        "{changed}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// `gonio library import` of `exchange` into `library`, which must succeed.
fn import(library: &Path, exchange: &Path) {
    let out = gonio()
        .args(["library", "--library"])
        .arg(library)
        .arg("import")
        .arg(exchange)
        .output()
        .expect("run gonio");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// A fixed small normal deviate per name and parameter (the questioned sheets of the test
/// above are reproducible given the library).
fn normal_at(name: &str, i: usize) -> f64 {
    let h = name.bytes().fold(i as u64 + 7, |h, b| {
        h.wrapping_mul(31).wrapping_add(b as u64)
    });
    ((h % 2001) as f64 / 1000.0 - 1.0) * 0.5
}
