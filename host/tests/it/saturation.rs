//! A sheet so bright that every reading saturates the detector (issue 28): the session
//! says that the readings saturated, on which range and how many, and what to change,
//! exits with the failure code and keeps what it measured; it no longer stops with the
//! fit's "only 0 distinct geometries" and a suggestion to resume (which would saturate
//! again).
use crate::cli_support::{self, gonio};
use std::path::Path;

/// Every raw reading of the folder's points.jsonl, as recorded.
fn points(dir: &Path) -> Vec<serde_json::Value> {
    std::fs::read_to_string(dir.join("points.jsonl"))
        .expect("points.jsonl is kept")
        .lines()
        .map(|l| serde_json::from_str(l).expect("one JSON object a line"))
        .collect()
}

#[test]
fn a_saturated_session_says_it_saturated_and_keeps_its_readings() {
    // ρd = 1000: over 250 times the white tile; the least sensitive range reads up to ~250.
    for (policy, dir_name) in [("adaptive", "points"), ("sweep", "sweep")] {
        let dir = cli_support::temp_dir("saturation", dir_name);
        let out = gonio(&[
            "measure",
            "--sim",
            "custom:5,10,1000,1.5",
            "--policy",
            policy,
            "--spots",
            "1",
            "--out",
            dir.to_str().unwrap(),
        ]);
        let err = cli_support::stderr(&out);
        assert_eq!(out.status.code(), Some(1), "{policy}: {err}");
        for said in [
            "the readings saturated the detector",
            "read full scale",
            "on range 2, the least sensitive of 3",
            "a radiance factor of at least",
            "--integration-ms",
            "does not help",
            "neutral-density filter",
            "the readings are kept in",
        ] {
            assert!(err.contains(said), "{policy}: '{said}' not in: {err}");
        }
        assert!(
            !err.contains("--resume"),
            "{policy}: suggests a resume: {err}"
        );
        assert!(dir.join("readings.csv").is_file(), "{policy}: readings.csv");
        assert!(dir.join("session.json").is_file(), "{policy}: session.json");
        let points = points(&dir);
        assert!(!points.is_empty(), "{policy}: no readings kept");
        assert!(
            points.iter().all(|p| p["reading"]["saturated"] == true),
            "{policy}: a reading not marked saturated"
        );
        // The count it gives is the folder's.
        assert!(
            err.contains(&format!("{} of {} readings", points.len(), points.len())),
            "{policy}: {} readings in the folder: {err}",
            points.len()
        );
        let _ = std::fs::remove_dir_all(&dir);
    }
}
