//! `gonio measure` end to end on the simulated instrument: the main job.

use serde_json::Value;
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

fn gonio(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_gonio")).args(args).stdin(Stdio::null()).output().expect("run gonio")
}

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("gonio-measure-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

fn result(out: &Output) -> Value {
    assert!(out.status.success(), "gonio failed: {}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).expect("one JSON object")
}

fn geometries(dir: &Path) -> Vec<(f64, f64)> {
    let session: Value = serde_json::from_slice(&std::fs::read(dir.join("session.json")).unwrap()).unwrap();
    session["readings"].as_array().unwrap().iter().map(|p| (p["theta_i_deg"].as_f64().unwrap(), p["theta_r_deg"].as_f64().unwrap())).collect()
}

fn assert_each_once(g: &[(f64, f64)]) {
    let mut sorted = g.to_vec();
    sorted.sort_by(|a, b| a.partial_cmp(b).unwrap());
    sorted.dedup();
    assert_eq!(sorted.len(), g.len(), "a geometry was recorded twice");
}

#[test]
fn every_paper_gets_its_class_with_the_papers_policy() {
    let expected = [("G", "G"), ("SG", "SG"), ("PPC", "rough-II"), ("MC", "rough-III"), ("J1", "rough-I"), ("J2", "rough-I"), ("J3", "rough-II"), ("J4", "rough-II")];
    for (sample, class) in expected {
        let dir = temp_dir(sample);
        let r = result(&gonio(&["measure", "--sim", sample, "--seed", "3", "--json", "--out", dir.to_str().unwrap()]));
        assert_eq!(r["class"], class, "{sample}: {r}");
        assert_eq!(r["sigma_ok"], true, "{sample}: {r}");
        for key in ["group", "sigma_deg", "rho_s", "rho_d", "eta", "nmae", "geometries", "device_seconds", "refinements", "class_confidence"] {
            assert!(r.get(key).is_some(), "{sample}: no {key}");
        }
        let refinements = r["refinements"].as_array().unwrap();
        if class.starts_with("rough") {
            assert!(refinements.is_empty(), "{sample}: rough papers need no refinement: {r}");
            assert_eq!(r["geometries"], 12);
        } else {
            // The paper: G passes σ_l at δ ≤ 3°, SG at δ ≤ 8°.
            let last = refinements.last().and_then(Value::as_u64).unwrap();
            assert!(if sample == "G" { last <= 3 } else { last <= 8 }, "{sample}: {r}");
        }
        let mut files = vec!["session.json", "readings.csv", "points.jsonl", "calibration.json", "astm-e1392.csv", "fig4-radiance-factor.svg", "fig5-sigma-rho_s.svg"];
        if class.starts_with("rough") {
            files.push("fig7-rho_s-rho_d.svg");
        }
        for file in files {
            assert!(dir.join(file).exists(), "{sample}: no {file}");
        }
        assert_each_once(&geometries(&dir));
        let _ = std::fs::remove_dir_all(&dir);
    }
}

#[test]
fn a_faulty_link_still_gives_the_same_class_and_every_geometry_once() {
    let clean_dir = temp_dir("clean");
    let faulty_dir = temp_dir("faulty");
    let clean = result(&gonio(&["measure", "--sim", "G", "--json", "--out", clean_dir.to_str().unwrap()]));
    let faulty = result(&gonio(&[
        "measure", "--sim", "G", "--json", "--faults", "corrupt=0.001,drop=0.001,unplug-at=5", "--out", faulty_dir.to_str().unwrap(),
    ]));
    assert_eq!(faulty["class"], clean["class"]);
    let g = geometries(&faulty_dir);
    assert_each_once(&g);
    assert_eq!(g.len(), geometries(&clean_dir).len());
    let session: Value = serde_json::from_slice(&std::fs::read(faulty_dir.join("session.json")).unwrap()).unwrap();
    let decisions = session["decisions"].to_string();
    assert!(decisions.contains("link lost"), "the unplug was noticed and recovered: {decisions}");
    let _ = std::fs::remove_dir_all(&clean_dir);
    let _ = std::fs::remove_dir_all(&faulty_dir);
}

#[test]
fn an_interrupted_session_resumes_measuring_only_what_is_missing() {
    let dir = temp_dir("resume");
    let full = result(&gonio(&["measure", "--sim", "SG", "--seed", "8", "--json", "--out", dir.to_str().unwrap()]));
    let all = geometries(&dir);
    // As if it had crashed after 20 readings, the last line cut short.
    let points = std::fs::read_to_string(dir.join("points.jsonl")).unwrap();
    let mut kept: String = points.lines().take(20).map(|l| format!("{l}\n")).collect();
    kept.push_str(&points.lines().nth(20).unwrap()[..30]);
    std::fs::write(dir.join("points.jsonl"), kept).unwrap();
    std::fs::remove_file(dir.join("session.json")).unwrap();
    let resumed = result(&gonio(&["measure", "--sim", "SG", "--seed", "8", "--json", "--resume", dir.to_str().unwrap()]));
    assert_eq!(resumed["class"], full["class"]);
    let g = geometries(&dir);
    assert_each_once(&g);
    assert_eq!(g.len(), all.len());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_stale_calibration_is_refused_with_its_age() {
    let dir = temp_dir("stale");
    result(&gonio(&["measure", "--sim", "MC", "--json", "--out", dir.to_str().unwrap()]));
    let path = dir.join("calibration.json");
    let mut calibration: Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    calibration["taken_unix_s"] = Value::from(calibration["taken_unix_s"].as_u64().unwrap() - 9 * 3600);
    std::fs::write(&path, calibration.to_string()).unwrap();
    let out = gonio(&["measure", "--sim", "MC", "--calibration", path.to_str().unwrap(), "--out", temp_dir("stale2").to_str().unwrap()]);
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("9.0 h old") && stderr.contains("limit is 8.0 h"), "{stderr}");
    // A fresh one is used as is: no white tile needed.
    let out = gonio(&["measure", "--sim", "MC", "--json", "--calibration", dir.to_str().unwrap(), "--max-calibration-age-h", "24", "--out", temp_dir("stale3").to_str().unwrap()]);
    assert_eq!(result(&out)["class"], "rough-III");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_session_through_the_pseudo_terminal_with_prompts() {
    let mut sim = Command::new(env!("CARGO_BIN_EXE_gonio"))
        .args(["sim", "PPC", "--seed", "2"])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut path = String::new();
    BufReader::new(sim.stdout.take().unwrap()).read_line(&mut path).unwrap();
    let dir = temp_dir("pty");
    let mut measure = Command::new(env!("CARGO_BIN_EXE_gonio"))
        .args(["measure", "--port", path.trim(), "--sample", "PPC", "--json", "--out", dir.to_str().unwrap()])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // The operator: white tile in, then the sample back.
    measure.stdin.take().unwrap().write_all(b"\n\n").unwrap();
    let out = measure.wait_with_output().unwrap();
    let _ = sim.kill();
    let _ = sim.wait();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("WHITE REFERENCE TILE"), "{stderr}");
    assert_eq!(result(&out)["class"], "rough-II");
    let _ = std::fs::remove_dir_all(&dir);
}
