//! `gonio fit DIR`: a finished session analysed again from its own folder (readings,
//! calibration, the settings and time it recorded) gives the result the session reported,
//! over samples, seeds, both policies, the realistic instrument, lost steps (superseded
//! readings) and a sheet of several spots; an unfinished folder is refused, saying why.
use crate::cli_support;
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
    assert!(out.status.success(), "{}", stderr(&out));
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
        assert!(gonio(&all).status.code().is_some_and(|c| c == 0 || c == 3));
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
    assert_eq!(
        (
            by("PPC")["kind"].as_str(),
            by("PPC")["classes"][0].as_str(),
            by("PPC")["ok"].as_bool()
        ),
        (Some("session"), Some("rough-II"), Some(true))
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
        text.contains("FLAGGED: lost-steps") && text.contains("rough-II"),
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
