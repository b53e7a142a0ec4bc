//! How a sheet lay on the port (orientation md/cd, side felt/wire): recorded from the
//! command line into session.json and sheet.json, and weighed by `gonio compare` — two
//! sheets measured in different stated orientations or sides are refused unless
//! `--allow-lay-mismatch`, and then flagged; a lay stated for one sheet only warns.
use serde_json::{Value, json};
use std::path::{Path, PathBuf};
use std::process::Command;

fn gonio() -> Command {
    let mut command = Command::new(env!("CARGO_BIN_EXE_gonio"));
    command.env(
        "XDG_DATA_HOME",
        std::env::temp_dir().join(format!("gonio-lay-no-library-{}", std::process::id())),
    );
    command
}

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("gonio-lay-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir
}

/// A session folder of a glossy sheet whose case states `case` (orientation, side).
fn session(dir: &Path, name: &str, sigma: f64, case: Value) -> PathBuf {
    let u = [0.02, 1.0, 0.005, 0.01];
    let cov: Vec<Vec<f64>> = (0..4)
        .map(|i| {
            (0..4)
                .map(|j| if i == j { u[i] * u[i] } else { 0.0 })
                .collect()
        })
        .collect();
    let doc = json!({
        "sample": name,
        "device": {"name": "sim"},
        "readings": [],
        "case": case,
        "result": {
            "sample": name,
            "sigma_deg": sigma, "rho_s": 57.8, "rho_d": 0.855, "eta": 1.19,
            "class": "G",
            "covariance": cov,
            "nmae": 0.01,
        }
    });
    let folder = dir.join(name);
    std::fs::create_dir_all(&folder).expect("folder");
    std::fs::write(folder.join("session.json"), doc.to_string()).expect("write");
    folder
}

fn compare(a: &Path, b: &Path, extra: &[&str]) -> std::process::Output {
    gonio()
        .args(["compare", "--json", "--demo-population"])
        .args(extra)
        .arg(a)
        .arg(b)
        .output()
        .expect("run gonio")
}

fn kinds(v: &Value) -> Vec<String> {
    v["warnings"]
        .as_array()
        .expect("warnings")
        .iter()
        .map(|w| w["kind"].as_str().unwrap_or("").to_string())
        .collect()
}

#[test]
fn sheets_measured_in_different_orientations_or_sides_are_not_compared_silently() {
    let dir = temp_dir("mismatch");
    let md_felt = session(
        &dir,
        "md-felt",
        0.8,
        json!({"orientation": "md", "side": "felt"}),
    );
    let md_felt_2 = session(
        &dir,
        "md-felt-2",
        0.81,
        json!({"orientation": "md", "side": "felt"}),
    );
    let cd_felt = session(
        &dir,
        "cd-felt",
        0.8,
        json!({"orientation": "cd", "side": "felt"}),
    );
    let md_wire = session(
        &dir,
        "md-wire",
        0.8,
        json!({"orientation": "md", "side": "wire"}),
    );
    let unknown = session(&dir, "unknown", 0.8, json!({"case_id": "K-1"}));

    // Both stated, different: refused, naming both.
    for (other, what, a, b) in [
        (&cd_felt, "orientation", "md", "cd"),
        (&md_wire, "side", "felt", "wire"),
    ] {
        let out = compare(&md_felt, other, &[]);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{what}: {stderr}");
        assert!(out.stdout.is_empty(), "{what}: nothing printed as a result");
        assert!(
            stderr.contains(&format!("different {what}s (A {a}, B {b})"))
                && stderr.contains("--allow-lay-mismatch"),
            "{stderr}"
        );
        // Allowed: compared, flagged, the warning first.
        let out = compare(&md_felt, other, &["--allow-lay-mismatch"]);
        assert_eq!(out.status.code(), Some(3), "{what}");
        let v: Value = serde_json::from_slice(&out.stdout).expect("JSON");
        assert_eq!(v["lay_differs"], true, "{v}");
        assert_eq!(kinds(&v)[0], "lay-differs", "{v}");
        assert_eq!(v["warnings"][0]["what"], what);
        assert_eq!(
            (v["a"][what].as_str(), v["b"][what].as_str()),
            (Some(a), Some(b))
        );
        let text = gonio()
            .args(["compare", "--demo-population", "--allow-lay-mismatch"])
            .arg(&md_felt)
            .arg(other)
            .output()
            .expect("run gonio");
        assert!(
            String::from_utf8_lossy(&text.stdout).contains("warning: LAY DIFFERS"),
            "{}",
            String::from_utf8_lossy(&text.stdout)
        );
    }

    // Stated for one only: compared with a warning.
    let out = compare(&md_felt, &unknown, &[]);
    assert_eq!(out.status.code(), Some(3));
    let v: Value = serde_json::from_slice(&out.stdout).expect("JSON");
    assert_eq!(v["lay_differs"], false);
    let k = kinds(&v);
    assert_eq!(k.iter().filter(|k| *k == "lay-unknown").count(), 2, "{k:?}");
    assert_eq!(v["b"]["orientation"], "unknown");

    // The same lay: nothing said of it.
    let out = compare(&md_felt, &md_felt_2, &[]);
    let v: Value = serde_json::from_slice(&out.stdout).expect("JSON");
    assert_eq!(v["lay_differs"], false);
    assert!(
        kinds(&v).iter().all(|k| !k.starts_with("lay-")),
        "{:?}",
        kinds(&v)
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_lay_given_is_recorded_in_session_and_sheet_and_a_resume_keeps_it() {
    let dir = temp_dir("recorded");
    let one = dir.join("one");
    let out = gonio()
        .args([
            "measure",
            "--sim",
            "SG",
            "--seed",
            "4",
            "--spots",
            "1",
            "--orientation",
            "cd",
            "--side",
            "wire",
            "--out",
        ])
        .arg(&one)
        .output()
        .expect("run gonio");
    assert!(
        out.status.success() || out.status.code() == Some(3),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        String::from_utf8_lossy(&out.stdout).contains("orientation cd, side wire"),
        "{}",
        String::from_utf8_lossy(&out.stdout)
    );
    let doc: Value =
        serde_json::from_str(&std::fs::read_to_string(one.join("session.json")).unwrap()).unwrap();
    assert_eq!(
        (
            doc["case"]["orientation"].as_str(),
            doc["case"]["side"].as_str()
        ),
        (Some("cd"), Some("wire"))
    );
    let report = std::fs::read_to_string(one.join("report.html")).unwrap_or_default();
    assert!(
        report.contains("side facing the instrument"),
        "the report shows the lay"
    );

    let sheet = dir.join("sheet");
    let out = gonio()
        .args([
            "measure",
            "--sim",
            "SG",
            "--seed",
            "5",
            "--spots",
            "2",
            "--orientation",
            "md",
            "--out",
        ])
        .arg(&sheet)
        .output()
        .expect("run gonio");
    assert!(
        out.status.success() || out.status.code() == Some(3),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let doc: Value =
        serde_json::from_str(&std::fs::read_to_string(sheet.join("sheet.json")).unwrap()).unwrap();
    assert_eq!(doc["case"]["orientation"], "md");
    assert!(
        doc["case"].get("side").is_none(),
        "unknown is absent: {doc}"
    );
    let spot: Value =
        serde_json::from_str(&std::fs::read_to_string(sheet.join("spot-2/session.json")).unwrap())
            .unwrap();
    assert_eq!(spot["case"]["orientation"], "md", "every spot records it");

    // A sheet in md against a session in cd: refused.
    let out = compare(&sheet, &one, &[]);
    assert_eq!(
        out.status.code(),
        Some(1),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let _ = std::fs::remove_dir_all(&dir);
}
