//! Bounds on every loop (issue 30 D4): a file that cannot be a session's is refused when a
//! resume reads it, at its line; a session that would measure the same readings again for
//! ever stops at its bound on re-measure rounds, and one whose folder is past its size at
//! that bound, each said in session.json, session.log (and sheet.json), with the command
//! that resumes. (The device-time bound has its unit test in `session::bounds`.)
use crate::common::in_process::measure as run;
use host::measure::Measured;
use host::output::folder::store::Crash;
use host::session::SessionError;
use serde_json::Value;
use std::path::{Path, PathBuf};

fn dir(name: &str) -> PathBuf {
    crate::common::in_process::ram_dir("bounds", name)
}

fn json(path: &Path) -> Value {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// A sweep session of G (`spots` spots) killed half-way through the writes of its
/// first spot; returns its folder and the writes a whole run makes.
fn killed(name: &str, spots: &str) -> (PathBuf, u64) {
    let count_dir = dir(&format!("{name}-count"));
    // One seed for both runs: the kill is half of this session's writes.
    let seed = crate::common::run_seed().to_string();
    let counting = Crash::counting();
    let out = count_dir.display().to_string();
    let whole = run(
        &[
            "--sim", "G", "--seed", &seed, "--policy", "sweep", "--spots", "1", "--out", &out,
        ],
        Some(counting.clone()),
    );
    assert!(matches!(whole, Ok(Measured::Done { .. })), "uninterrupted");
    let _ = std::fs::remove_dir_all(&count_dir);
    let writes = counting.writes();
    let out = dir(name);
    let text = out.display().to_string();
    let first = run(
        &[
            "--sim", "G", "--seed", &seed, "--policy", "sweep", "--spots", spots, "--out", &text,
        ],
        Some(Crash::at(writes / 2)),
    );
    assert!(
        !matches!(first, Ok(Measured::Done { .. } | Measured::Sheet { .. })),
        "killed"
    );
    (out, writes)
}

/// The resume, with a cap on its writes (a loop that never ends fails the test instead
/// of hanging it).
fn resume(out: &Path, writes: u64, cap: u64) -> anyhow::Result<Measured> {
    run(
        &[
            "--sim",
            "G",
            "--policy",
            "sweep",
            "--resume",
            &out.display().to_string(),
        ],
        Some(Crash::at(writes * cap)),
    )
}

/// Every number of `value` set to 0 but the calibration's time (kept, so that its age is
/// not what refuses it).
fn zero_numbers(value: &mut Value, key: &str) {
    match value {
        Value::Number(_) if key != "taken_unix_s" => *value = Value::from(0),
        Value::Array(items) => items.iter_mut().for_each(|v| zero_numbers(v, key)),
        Value::Object(map) => map.iter_mut().for_each(|(k, v)| zero_numbers(v, k)),
        _ => {}
    }
}

#[test]
fn a_zeroed_calibration_is_refused_on_resume_at_its_file_and_line() {
    let (out, writes) = killed("zeroed", "1");
    let path = out.join("calibration.json");
    let mut calibration = json(&path);
    zero_numbers(&mut calibration, "");
    std::fs::write(&path, serde_json::to_string_pretty(&calibration).unwrap()).unwrap();
    let before = std::fs::read(out.join("points.jsonl")).unwrap();
    match resume(&out, writes, 20) {
        Err(e) => {
            let text = format!("{e:#}");
            let at = format!("{}:", path.display());
            assert!(
                text.contains(&at) && text.contains("white_radiance_factor"),
                "the refusal names the file, line and field: {text}"
            );
        }
        Ok(Measured::Stopped { error, .. }) => panic!("resumed, then stopped: {error}"),
        Ok(_) => panic!("a zeroed calibration was resumed"),
    }
    assert_eq!(
        std::fs::read(out.join("points.jsonl")).unwrap(),
        before,
        "nothing written"
    );
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn a_reading_of_1e308_in_points_jsonl_is_refused_on_resume_at_its_line() {
    let (out, writes) = killed("huge", "1");
    let path = out.join("points.jsonl");
    // Its whole lines (a line the kill cut short is the resume's to repair).
    let text = std::fs::read_to_string(&path).unwrap();
    let original = text[..=text.rfind('\n').unwrap()].to_string();
    let lines: Vec<String> = original.lines().map(str::to_string).collect();
    assert!(lines.len() > 5, "readings recorded before the kill");
    for (field, line) in [("mean_counts", 5usize), ("theta_r_deg", 3)] {
        let mut changed = lines.clone();
        let mut value: Value = serde_json::from_str(&changed[line - 1]).unwrap();
        match field {
            "mean_counts" => value["reading"]["mean_counts"] = serde_json::json!(1e308),
            _ => value[field] = serde_json::json!(1e308),
        }
        changed[line - 1] = serde_json::to_string(&value).unwrap();
        std::fs::write(&path, changed.join("\n") + "\n").unwrap();
        match resume(&out, writes, 20) {
            Err(e) => {
                let text = format!("{e:#}");
                assert!(
                    text.contains(&format!("{}:{line}", path.display())),
                    "the refusal names the file and line of {field}: {text}"
                );
            }
            Ok(Measured::Stopped { error, .. }) => {
                panic!("{field}: resumed, then stopped: {error}")
            }
            Ok(_) => panic!("{field}: a reading of 1e308 was resumed"),
        }
        assert_eq!(text_lines(&path), changed, "{field}: nothing written");
        std::fs::write(&path, &original).unwrap();
    }
    let _ = std::fs::remove_dir_all(&out);
}

fn text_lines(path: &Path) -> Vec<String> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .map(str::to_string)
        .collect()
}

/// The session's record of a stop at a bound: session.json's status and why, the same
/// in session.log, and the command that resumes.
fn stopped_at(dir: &Path, bound: &str) {
    let session = json(&dir.join("session.json"));
    assert_eq!(session["status"], "failed", "{session}");
    let why = session["why"].as_str().unwrap_or_default();
    assert!(why.contains(bound), "session.json says why: {why}");
    assert!(
        session["resume_with"]
            .as_str()
            .is_some_and(|c| c.contains("--resume")),
        "and how to resume: {}",
        session["resume_with"]
    );
    let log = std::fs::read_to_string(dir.join("session.log")).unwrap();
    assert!(log.contains(bound), "session.log says it too");
}

#[test]
fn a_calibration_that_converts_nothing_at_one_incidence_stops_at_the_round_bound() {
    // A sheet of two spots killed in spot 1; its calibration then loses the white reading
    // at θi = 60°: every bin of the 60° sweep is unconvertible, the sweep is never covered
    // and was measured again for ever ("round 901").
    let (out, writes) = killed("rounds", "2");
    let path = out.join("spot-1/calibration.json");
    let mut calibration = json(&path);
    let white = calibration["white"].as_array_mut().unwrap();
    let before = white.len();
    white.retain(|w| w["theta_i_deg"].as_f64() != Some(60.0));
    assert_eq!(white.len() + 1, before, "one white reading at 60°");
    std::fs::write(&path, serde_json::to_string_pretty(&calibration).unwrap()).unwrap();
    let bound = "bound on re-measure rounds";
    match resume(&out, writes, 200) {
        Ok(Measured::Stopped {
            error: SessionError::Bound(text),
            record_error: None,
            ..
        }) => assert!(text.contains(bound), "{text}"),
        Ok(Measured::Stopped { error, .. }) => panic!("stopped otherwise: {error}"),
        Ok(_) => panic!("finished"),
        Err(e) => panic!("{e:#}"),
    }
    stopped_at(&out.join("spot-1"), bound);
    let sheet = json(&out.join("sheet.json"));
    assert!(
        sheet["why"].as_str().is_some_and(|w| w.contains(bound)),
        "sheet.json says why: {sheet}"
    );
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn a_folder_past_its_size_bound_stops_the_session_saying_so() {
    let (out, writes) = killed("size", "1");
    // A file the size of the bound (sparse: no disk is used).
    let padding = std::fs::File::create(out.join("padding")).unwrap();
    padding
        .set_len(host::session::bounds::MAX_FOLDER_BYTES)
        .unwrap();
    let bound = "bound on the folder's size";
    match resume(&out, writes, 20) {
        Ok(Measured::Stopped {
            error: SessionError::Bound(text),
            record_error: None,
            ..
        }) => assert!(text.contains(bound), "{text}"),
        Ok(Measured::Stopped { error, .. }) => panic!("stopped otherwise: {error}"),
        Ok(_) => panic!("finished"),
        Err(e) => panic!("{e:#}"),
    }
    stopped_at(&out, bound);
    let _ = std::fs::remove_dir_all(&out);
}
