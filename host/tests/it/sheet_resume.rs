//! A sheet resumed after interruptions (issue 30): after two kills it still resumes (D1),
//! and every spot, resumed or not, is measured under the plan the sheet recorded once (D2).
use crate::common::in_process::measure as run;
use host::measure::Measured;
use host::output::folder::store::Crash;
use host::output::folder::verify::verify_sheet;
use host::output::report::draw;
use std::path::{Path, PathBuf};

fn dir(name: &str) -> PathBuf {
    crate::common::in_process::ram_dir("sheet-resume", name)
}

fn json(path: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn finished(measured: anyhow::Result<Measured>, what: &str) {
    match measured {
        Ok(Measured::Sheet { .. }) => {}
        Ok(Measured::Done { .. }) => panic!("{what}: measured one spot, not a sheet"),
        Ok(Measured::Stopped { error, .. }) => panic!("{what}: stopped: {error}"),
        Err(e) => panic!("{what}: {e:#}"),
    }
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).expect("copy");
    for entry in std::fs::read_dir(from).expect("copy") {
        let path = entry.expect("copy").path();
        let target = to.join(path.file_name().expect("a name"));
        if path.is_dir() {
            copy_dir(&path, &target);
        } else {
            std::fs::copy(&path, &target).expect("copy");
        }
    }
}

/// The writes of an uninterrupted two-spot sweep sheet of G (counted in a folder of the
/// test's own: the tests run at once).
fn writes_of_a_sweep_sheet(test: &str) -> u64 {
    let out = dir(&format!("count-{test}"));
    let counting = Crash::counting();
    finished(
        run(
            &[
                "--sim",
                "G",
                "--policy",
                "sweep",
                "--spots",
                "2",
                "--out",
                &out.display().to_string(),
            ],
            Some(counting.clone()),
        ),
        "uninterrupted",
    );
    let _ = std::fs::remove_dir_all(&out);
    counting.writes()
}

#[test]
fn a_sweep_sheet_killed_in_spot_1_and_again_in_spot_2_resumes() {
    let writes = writes_of_a_sweep_sheet("twice");
    let out = dir("twice");
    let out_text = out.display().to_string();
    // Killed in spot 1's first pass, before spot 1 calibrated its gain ratios on the sample.
    let first = run(
        &[
            "--sim", "G", "--policy", "sweep", "--spots", "2", "--out", &out_text,
        ],
        Some(Crash::at(writes / 5)),
    );
    assert!(!matches!(first, Ok(Measured::Sheet { .. })));
    let ratios = json(&out.join("spot-1/calibration.json"))["gain_ratios"].clone();
    assert_eq!(
        ratios,
        serde_json::json!([]),
        "killed before the gain ratios"
    );
    assert!(!out.join("spot-2").exists(), "killed in spot 1");
    // Resumed, spot 1 finishes, and the resume is killed in spot 2 (three quarters of the
    // way through the writes the resume makes, counted on a copy).
    let copy = dir("twice-copy");
    copy_dir(&out, &copy);
    let counting = Crash::counting();
    finished(
        run(
            &[
                "--sim",
                "G",
                "--policy",
                "sweep",
                "--resume",
                &copy.display().to_string(),
            ],
            Some(counting.clone()),
        ),
        "resumed once",
    );
    let _ = std::fs::remove_dir_all(&copy);
    let second = run(
        &["--sim", "G", "--policy", "sweep", "--resume", &out_text],
        Some(Crash::at(counting.writes() * 3 / 4)),
    );
    assert!(!matches!(second, Ok(Measured::Sheet { .. })));
    assert!(
        out.join("spot-1/MANIFEST.sha256").is_file(),
        "spot 1 finished"
    );
    assert!(
        out.join("spot-2/session.json").is_file(),
        "killed in spot 2"
    );
    // Spot 2 was handed spot 1's calibration as spot 1 finished it.
    assert_eq!(
        json(&out.join("spot-1/calibration.json")),
        json(&out.join("spot-2/calibration.json")),
        "one calibration for the sheet"
    );
    finished(
        run(
            &["--sim", "G", "--policy", "sweep", "--resume", &out_text],
            None,
        ),
        "resumed after two kills",
    );
    verify_sheet(&out, draw).unwrap_or_else(|p| panic!("{p:?}"));
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn a_sweep_sheet_resumed_without_its_policy_measures_every_spot_under_the_sheets_plan() {
    let writes = writes_of_a_sweep_sheet("plan");
    let out = dir("plan");
    let out_text = out.display().to_string();
    let first = run(
        &[
            "--sim", "G", "--policy", "sweep", "--spots", "2", "--out", &out_text,
        ],
        Some(Crash::at(writes / 5)),
    );
    assert!(!matches!(first, Ok(Measured::Sheet { .. })));
    assert!(!out.join("spot-2").exists(), "killed in spot 1");
    let plan = json(&out.join("sheet.json"))["plan"].clone();
    assert_eq!(
        plan["policy"], "sweep",
        "the sheet records its plan: {plan}"
    );
    // A resume that would change the plan is refused by name, nothing changed.
    let before = std::fs::read(out.join("sheet.json")).expect("sheet.json");
    match run(
        &["--sim", "G", "--policy", "adaptive", "--resume", &out_text],
        None,
    ) {
        Err(e) => assert!(
            e.to_string()
                .contains("--policy adaptive differs from the sheet's plan: sweep"),
            "{e:#}"
        ),
        Ok(_) => panic!("a resume under another policy was not refused"),
    }
    assert_eq!(
        std::fs::read(out.join("sheet.json")).expect("sheet.json"),
        before
    );
    // The command the sheet says continues it is enough.
    let resume_with = json(&out.join("sheet.json"))["resume_with"]
        .as_str()
        .expect("resume_with")
        .to_string();
    let words: Vec<&str> = resume_with.split(' ').skip(2).collect();
    assert_eq!(words, ["--sim", "G", "--resume", out_text.as_str()]);
    finished(run(&words, None), "resumed as resume_with says");
    for spot in ["spot-1", "spot-2"] {
        let session = json(&out.join(spot).join("session.json"));
        assert_eq!(
            session["plan"], plan,
            "{spot} is measured under the sheet's plan"
        );
    }
    assert_eq!(json(&out.join("sheet.json"))["plan"], plan);
    verify_sheet(&out, draw).unwrap_or_else(|p| panic!("{p:?}"));
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn a_sheet_killed_before_its_first_spot_began_resumes_under_the_plan_it_began_with() {
    // The first sheet.json was written without the plan (recorded a write later): a kill
    // between the two left a sheet that a resume without --policy measured under the
    // default adaptive policy (the interruption campaign's sheet 278 of seed 2).
    let args = |out: &str| -> Vec<String> {
        [
            "--sim", "PPC", "--policy", "paper", "--spots", "2", "--case", "K-1", "--out", out,
        ]
        .iter()
        .map(|s| s.to_string())
        .collect()
    };
    let mut resumed = false;
    for n in 1..=8 {
        let out = dir(&format!("first-{n}"));
        let out_text = out.display().to_string();
        let list = args(&out_text);
        let list: Vec<&str> = list.iter().map(String::as_str).collect();
        let first = run(&list, Some(Crash::at(n)));
        assert!(!matches!(first, Ok(Measured::Sheet { .. })), "write {n}");
        if !out.join("sheet.json").exists() {
            let _ = std::fs::remove_dir_all(&out);
            continue;
        }
        let sheet = json(&out.join("sheet.json"));
        assert_eq!(
            sheet["plan"]["policy"], "paper",
            "killed at write {n}: {sheet}"
        );
        assert_eq!(
            sheet["case"]["case_id"], "K-1",
            "killed at write {n}: {sheet}"
        );
        if !resumed {
            finished(
                run(&["--sim", "PPC", "--resume", &out_text], None),
                "resumed",
            );
            for spot in ["spot-1", "spot-2"] {
                let session = json(&out.join(spot).join("session.json"));
                assert_eq!(session["plan"]["policy"], "paper", "{spot}");
            }
            resumed = true;
        }
        let _ = std::fs::remove_dir_all(&out);
    }
    assert!(resumed, "no kill left a sheet.json");
}
