//! `gonio fit DIR`: a finished session analysed again from its own folder (readings,
//! calibration, the settings and time it recorded) gives the result the session reported,
//! over samples, seeds, both policies, the realistic instrument, lost steps (superseded
//! readings) and a sheet of several spots; an unfinished folder is refused, saying why.
use crate::cli_support;
use crate::common::run_seed;
use cli_support::{gonio, stderr, temp_dir};

fn refit(dir: &std::path::Path) -> Vec<serde_json::Value> {
    let out = gonio(&["fit", "--json", dir.to_str().unwrap()]);
    assert!(
        out.status.code().is_some_and(|c| c == 0 || c == 3),
        "{}",
        stderr(&out)
    );
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).expect("JSON"))
        .collect()
}

#[test]
fn a_session_analysed_again_from_its_folder_gives_the_result_it_reported() {
    let cases: [&[&str]; 6] = [
        &["--sim", "G", "--seed", "3"],
        &["--sim", "SG", "--seed", "4", "--physics", "real"],
        &["--sim", "PPC", "--seed", "5", "--policy", "paper"],
        &[
            "--sim",
            "J1",
            "--seed",
            "6",
            "--faults",
            "lose-steps=detector:40",
        ],
        &[
            "--sim",
            "G",
            "--seed",
            "7",
            "--lobe",
            "cauchy",
            "--physics",
            "real",
        ],
        &[
            "--sim",
            "MC",
            "--seed",
            "8",
            "--arm-zero-uncertainty-deg",
            "0.3",
            "--integration-ms",
            "50",
        ],
    ];
    for (k, case) in cases.iter().enumerate() {
        let dir = temp_dir("reanalysis", &k.to_string());
        let mut args = vec!["measure", "--spots", "1", "--out", dir.to_str().unwrap()];
        args.extend_from_slice(case);
        let out = gonio(&args);
        assert!(
            out.status.code().is_some_and(|c| c == 0 || c == 3),
            "{case:?}: {}",
            stderr(&out)
        );
        let results = refit(&dir);
        assert_eq!(results.len(), 1);
        let r = &results[0];
        assert_eq!(
            r["same_as_session"], true,
            "{case:?}: differs in {}",
            r["differs_from_session_in"]
        );
        let session: serde_json::Value =
            serde_json::from_slice(&std::fs::read(dir.join("session.json")).unwrap()).unwrap();
        for key in [
            "sigma_deg",
            "rho_s",
            "rho_d",
            "ci95",
            "class",
            "class_confidence",
            "budget",
            "gof_p",
        ] {
            assert_eq!(r[key], session["result"][key], "{case:?}: {key}");
        }
        // The analysis's own flags are among the session's (which add lost steps, a resume…).
        for flag in r["flags"].as_array().unwrap() {
            assert!(
                session["result"]["flags"]
                    .as_array()
                    .unwrap()
                    .contains(flag),
                "{case:?}: {flag}"
            );
        }
        let _ = std::fs::remove_dir_all(&dir);
    }
}

#[test]
fn every_spot_of_a_sheet_is_analysed_again_and_an_unfinished_folder_is_refused() {
    let dir = temp_dir("reanalysis", "sheet");
    let out = gonio(&[
        "measure",
        "--sim",
        "PPC",
        "--spots",
        "2",
        "--sheet-variation",
        "3",
        "--out",
        dir.to_str().unwrap(),
    ]);
    cli_support::assert_finished(&out);
    let results = refit(&dir);
    assert_eq!(results.len(), 2, "one result per spot");
    assert!(
        results.iter().all(|r| r["same_as_session"] == true),
        "{results:?}"
    );
    assert_ne!(
        results[0]["sigma_deg"], results[1]["sigma_deg"],
        "two spots of the sheet"
    );
    // A folder whose session did not finish: refused with the reason.
    let session = dir.join("spot-1/session.json");
    let text = std::fs::read_to_string(&session).unwrap();
    std::fs::write(
        &session,
        text.replacen("\"status\": \"finished\"", "\"status\": \"interrupted\"", 1),
    )
    .unwrap();
    let out = gonio(&["fit", dir.join("spot-1").to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(1));
    assert!(stderr(&out).contains("not finished"), "{}", stderr(&out));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn gonio_sessions_lists_sessions_and_sheets_with_their_state() {
    let root = temp_dir("reanalysis", "catalogue");
    let r = root.to_str().unwrap();
    for (name, args) in [
        ("a", vec!["--sim", "PPC", "--spots", "1"]),
        ("b", vec!["--sim", "SG", "--spots", "2"]),
        (
            "c",
            vec![
                "--sim",
                "J1",
                "--spots",
                "1",
                "--faults",
                "lose-steps=detector:40",
            ],
        ),
    ] {
        let dir = root.join(name);
        let mut all = vec!["measure", "--out", dir.to_str().unwrap()];
        all.extend(args);
        cli_support::assert_finished(&gonio(&all));
    }
    std::fs::create_dir_all(root.join("not-a-session")).unwrap();
    let out = gonio(&["sessions", r, "--json"]);
    assert!(out.status.success(), "{}", stderr(&out));
    let rows: Vec<serde_json::Value> = String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(rows.len(), 3, "{rows:?}");
    let by = |sample: &str| {
        rows.iter()
            .find(|r| r["sample"] == sample)
            .unwrap_or_else(|| panic!("{sample} listed"))
    };
    // PPC's seed is drawn for the run: its class and state are listed as its session.json
    // has them (a flagged one too: lack-of-fit on 2 in 1,000 seeds).
    let ppc: serde_json::Value =
        serde_json::from_slice(&std::fs::read(root.join("a/session.json")).unwrap()).unwrap();
    assert_eq!(
        (
            by("PPC")["kind"].as_str(),
            by("PPC")["classes"][0].as_str(),
            by("PPC")["ok"].as_bool()
        ),
        (
            Some("session"),
            ppc["result"]["class"].as_str(),
            ppc["ok"].as_bool()
        )
    );
    assert_eq!(
        (
            by("SG")["kind"].as_str(),
            by("SG")["classes"].as_array().map(Vec::len)
        ),
        (Some("sheet"), Some(2))
    );
    assert_eq!(by("J1")["ok"], false);
    assert!(
        by("J1")["flags"]
            .as_array()
            .unwrap()
            .iter()
            .any(|f| f == "lost-steps")
    );
    assert!(
        rows.iter()
            .all(|r| r["device_seconds"].as_f64().is_some_and(|s| s > 1.0))
    );
    let text = String::from_utf8_lossy(&gonio(&["sessions", r]).stdout).into_owned();
    assert!(
        text.contains("FLAGGED: lost-steps")
            && text.contains(ppc["result"]["class"].as_str().unwrap_or("undecided")),
        "{text}"
    );
    let out = gonio(&["sessions", root.join("nothing").to_str().unwrap()]);
    assert!(
        !out.status.success() && stderr(&out).contains("no folder"),
        "{}",
        stderr(&out)
    );
    let _ = std::fs::remove_dir_all(&root);
}

/// `gonio fit --json FILE…`: its exit code and its JSON lines.
fn fit_json(files: &[&std::path::Path]) -> (Option<i32>, Vec<serde_json::Value>, String) {
    let mut args = vec!["fit", "--json"];
    args.extend(files.iter().map(|f| f.to_str().unwrap()));
    let out = gonio(&args);
    let lines = String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).expect("JSON"))
        .collect();
    (out.status.code(), lines, stderr(&out))
}

/// Agreement of two JSON numbers to numerical precision: readings.csv holds the numbers
/// the session fitted (a still reading's angles without their last bits of float noise),
/// 10⁻⁹ relative (both null also agree).
fn close(a: &serde_json::Value, b: &serde_json::Value) -> bool {
    match (a.as_f64(), b.as_f64()) {
        (Some(x), Some(y)) => (x - y).abs() <= 1e-9 * x.abs().max(y.abs()) + 1e-12,
        _ => a == b,
    }
}

/// The folder's `readings.csv` and `readings.shared-errors.json`, copied alone into a
/// folder of their own, re-analyse to the session's σ, ρs, ρd, class, confidence and
/// flags under the session's sample name: a sweep session, an adaptive one and a spot of a
/// sheet, on this run's seed. Without the shared-errors file the same readings are fitted
/// on their own noise (a note says so), and an edited CSV is refused naming both files.
#[test]
fn readings_csv_with_its_shared_errors_alone_reanalyses_to_the_sessions_result() {
    let seed = run_seed();
    let root = temp_dir("reanalysis", "alone");
    let cases: [(&str, Vec<String>, &str); 3] = [
        (
            "sweep",
            vec![
                "--sim".into(),
                "G".into(),
                "--policy".into(),
                "sweep".into(),
                "--spots".into(),
                "1".into(),
            ],
            "",
        ),
        (
            "adaptive",
            vec![
                "--sim".into(),
                "PPC".into(),
                "--policy".into(),
                "adaptive".into(),
                "--spots".into(),
                "1".into(),
                "--physics".into(),
                "real".into(),
            ],
            "",
        ),
        (
            "sheet",
            vec![
                "--sim".into(),
                "SG".into(),
                "--spots".into(),
                "2".into(),
                "--sheet-variation".into(),
                "3".into(),
            ],
            "spot-2",
        ),
    ];
    for (k, (name, case, spot)) in cases.iter().enumerate() {
        let dir = root.join(name);
        let seed_text = (seed + k as u64).to_string();
        let mut args = vec![
            "measure",
            "--seed",
            &seed_text,
            "--out",
            dir.to_str().unwrap(),
        ];
        args.extend(case.iter().map(String::as_str));
        let out = gonio(&args);
        assert!(
            out.status.code().is_some_and(|c| c == 0 || c == 3),
            "{name}: {}",
            stderr(&out)
        );
        let folder = dir.join(spot);
        let session: serde_json::Value =
            serde_json::from_slice(&std::fs::read(folder.join("session.json")).unwrap()).unwrap();
        let recorded = &session["result"];
        // The folder's own re-analysis, for the flags the analysis itself raises.
        let (folder_code, again, err) = fit_json(&[&folder]);
        assert_eq!(again.len(), 1, "{name}: {err}");
        assert_eq!(again[0]["same_as_session"], true, "{name}");
        // The two files alone.
        let alone = root.join(format!("{name}-alone"));
        std::fs::create_dir_all(&alone).unwrap();
        for file in ["readings.csv", "readings.shared-errors.json"] {
            std::fs::copy(folder.join(file), alone.join(file))
                .unwrap_or_else(|e| panic!("{name}: {file}: {e}"));
        }
        let csv = alone.join("readings.csv");
        let (code, results, err) = fit_json(&[&csv]);
        assert_eq!(results.len(), 1, "{name}: {err}");
        let r = &results[0];
        assert_eq!(
            r["sample"], session["sample"],
            "{name}: the sample's name kept"
        );
        for key in [
            "sigma_deg",
            "rho_s",
            "rho_d",
            "eta",
            "class_confidence",
            "gof_p",
        ] {
            assert!(
                close(&r[key], &recorded[key]),
                "{name} (seed {seed}): {key} {} against the session's {}",
                r[key],
                recorded[key]
            );
        }
        for key in ["class", "group", "n", "dof"] {
            assert_eq!(r[key], recorded[key], "{name} (seed {seed}): {key}");
        }
        for (p, q) in r["ci95"]["sigma_deg"].as_array().into_iter().flatten().zip(
            recorded["ci95"]["sigma_deg"]
                .as_array()
                .into_iter()
                .flatten(),
        ) {
            assert!(close(p, q), "{name}: σ's interval {p} against {q}");
        }
        assert_eq!(r["flags"], again[0]["flags"], "{name} (seed {seed}): flags");
        assert_eq!(code, folder_code, "{name}: exit code");
        // In its folder, readings.csv finds its shared errors too.
        let (_, in_folder, err) = fit_json(&[&folder.join("readings.csv")]);
        assert_eq!(in_folder.len(), 1, "{name}: {err}");
        assert!(
            close(&in_folder[0]["sigma_deg"], &recorded["sigma_deg"]),
            "{name}"
        );
        // Copied without them: the readings' own noise and the file's name.
        let lone = alone.join("lone.csv");
        std::fs::copy(&csv, &lone).unwrap();
        let (_, lone_results, err) = fit_json(&[&lone]);
        assert_eq!(lone_results.len(), 1, "{name}: {err}");
        assert_eq!(lone_results[0]["sample"], "lone", "{name}");
        // An edited CSV: refused, naming the shared-errors file and what to do.
        let text = std::fs::read_to_string(&csv).unwrap();
        std::fs::write(&csv, text.replacen('\n', "\n# edited\n", 1)).unwrap();
        let (code, results, err) = fit_json(&[&csv]);
        assert_eq!(code, Some(1), "{name}: {err}");
        assert!(results.is_empty());
        assert!(
            err.contains("readings.shared-errors.json") && err.contains("SHA-256"),
            "{name}: {err}"
        );
    }
    let _ = std::fs::remove_dir_all(&root);
}

/// A folder written before the shared-errors file (the first version's): its
/// `readings.csv` is still fitted, with a note that the session's shared errors are left
/// out and how to re-analyse the folder.
#[test]
fn an_old_folders_readings_csv_is_fitted_with_a_note_on_what_it_lacks() {
    let data = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/v1-session-G/readings.csv");
    let (code, results, err) = fit_json(&[&data]);
    assert!(code.is_some_and(|c| c == 0 || c == 3), "{err}");
    assert_eq!(results.len(), 1);
    assert!(
        err.contains("no readings.shared-errors.json beside it") && err.contains("gonio fit"),
        "{err}"
    );
}
