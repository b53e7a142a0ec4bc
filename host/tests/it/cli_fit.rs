//! `gonio fit` end to end: JSON Lines keys, several samples and files, and errors that
//! name file:line without losing the other files' results.
use crate::common;
use std::path::PathBuf;
use std::process::Command;

fn gonio() -> Command {
    Command::new(env!("CARGO_BIN_EXE_gonio"))
}

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("gonio-cli-fit-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir
}

fn csv(samples: &[(&str, Vec<host::analysis::fit::Observation>)], with_sample: bool) -> String {
    let mut s = String::from(if with_sample {
        "sample,theta_i,theta_r,radiance_factor\n"
    } else {
        "theta_i,theta_r,radiance_factor\n"
    });
    for (name, obs) in samples {
        for o in obs {
            if with_sample {
                s += &format!("{name},");
            }
            s += &format!(
                "{},{},{}\n",
                o.theta_i_deg, o.theta_r_deg, o.radiance_factor
            );
        }
    }
    s
}

#[test]
fn json_lines_for_many_samples_and_files_with_errors_located() {
    let dir = temp_dir("json");
    let g = common::noisy(&common::reference("G"), &common::strategy2(2), 1);
    let j1 = common::noisy(&common::reference("J1"), &common::strategy1_m12(), 2);
    let mc = common::noisy(&common::reference("MC"), &common::full_grid(), 3);
    let multi = dir.join("archive.csv");
    std::fs::write(&multi, csv(&[("G-sheet", g), ("J1-sheet", j1)], true)).expect("write");
    let single = dir.join("mc_paper.csv");
    std::fs::write(&single, csv(&[("x", mc)], false)).expect("write");
    let bad = dir.join("broken.csv");
    std::fs::write(
        &bad,
        "theta_i,theta_r,radiance_factor\n20,0,0.5\n20,20,nope\n",
    )
    .expect("write");
    let bad_fit = dir.join("negative.csv");
    std::fs::write(
        &bad_fit,
        "theta_i,theta_r,radiance_factor\n20,0,0.5\n20,20,3\n30,0,0.5\n30,30,-4\n45,0,0.5\n",
    )
    .expect("write");

    let out = gonio()
        .args(["fit", "--json"])
        .arg(&multi)
        .arg(&bad)
        .arg(&single)
        .arg(&bad_fit)
        .output()
        .expect("run gonio");
    assert!(
        !out.status.success(),
        "a bad file makes the exit status non-zero"
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("broken.csv:3:"), "{stderr}");
    assert!(
        stderr.contains("negative.csv:5:") && stderr.contains("negative"),
        "{stderr}"
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    let lines: Vec<serde_json::Value> = stdout
        .lines()
        .map(|l| serde_json::from_str(l).expect("JSON Lines"))
        .collect();
    assert_eq!(lines.len(), 3, "{stdout}");
    let keys = [
        "sample",
        "n",
        "sigma_deg",
        "rho_s",
        "rho_d",
        "eta",
        "nmae",
        "delta_deg",
        "sigma_l_deg",
        "sigma_ok",
        "group",
        "class",
        "class_confidence",
        "nearest_reference",
        "ci95",
        "model",
    ];
    for line in &lines {
        for k in keys {
            assert!(line.get(k).is_some(), "missing {k} in {line}");
        }
    }
    assert_eq!(lines[0]["sample"], "G-sheet");
    assert_eq!(lines[0]["class"], "G");
    assert_eq!(lines[0]["delta_deg"], 2.0);
    assert_eq!(lines[0]["sigma_ok"], true);
    assert_eq!(lines[1]["sample"], "J1-sheet");
    assert_eq!(lines[1]["group"], "rough");
    assert_eq!(lines[1]["class"], "rough-I");
    assert_eq!(lines[1]["delta_deg"], 35.0);
    assert_eq!(
        lines[2]["sample"], "mc_paper",
        "file stem without a sample column"
    );
    assert_eq!(lines[2]["class"], "rough-III");
    assert_eq!(lines[2]["nearest_reference"], "MC");
    assert!(
        lines[2]["ci95"]["sigma_deg"]
            .as_array()
            .is_some_and(|a| a.len() == 2)
    );

    // --delta overrides; the table output works too.
    let out = gonio()
        .args(["fit", "--delta", "0.5"])
        .arg(&multi)
        .output()
        .expect("run gonio");
    assert!(out.status.success());
    let table = String::from_utf8_lossy(&out.stdout);
    assert!(
        table.contains("G-sheet") && table.contains("δ 0.500°") && table.contains("class G"),
        "{table}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_missing_file_is_an_error_naming_it() {
    let out = gonio()
        .args(["fit", "/nonexistent/file.csv"])
        .output()
        .expect("run gonio");
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("/nonexistent/file.csv"));
}

/// A gross outlier in a table without uncertainties is named by the file's line, the one
/// a user opens the file at (a comment and a blank line before the data move it), and the
/// result is flagged.
#[test]
fn an_outlier_is_named_by_its_line_in_the_file() {
    let dir = temp_dir("outlier-line");
    let mut g = common::noisy(&common::reference("G"), &common::strategy2(2), 7);
    let k = 10;
    g[k].radiance_factor *= 1000.0;
    let table = csv(&[("x", g.clone())], false);
    let (header, rows) = table.split_once('\n').expect("a header");
    let path = dir.join("g_outlier.csv");
    std::fs::write(&path, format!("# one reading ×1000\n\n{header}\n{rows}")).expect("write");
    let out = gonio()
        .args(["fit", path.to_str().expect("utf-8"), "--json"])
        .output()
        .expect("run gonio");
    let stdout = String::from_utf8_lossy(&out.stdout);
    // The comment, the blank line and the header come first: reading k is on line k + 4.
    let line = k + 4;
    assert!(
        stdout.contains("\"outlier\"") && stdout.contains(&format!("\"line\":{line}")),
        "{stdout}"
    );
    let text = gonio()
        .args(["fit", path.to_str().expect("utf-8")])
        .output()
        .expect("run gonio");
    let text = String::from_utf8_lossy(&text.stdout);
    assert!(
        text.contains(&format!("the reading on line {line} ")),
        "{text}"
    );
}

#[test]
fn text_from_a_csv_reaches_the_terminal_escaped_and_a_bad_field_is_quoted_short() {
    // Issue 30: a sample name holding escape sequences went to the terminal as is, and a
    // 50 MB field came back whole in the error.
    let dir = temp_dir("hostile");
    let g = common::noisy(&common::reference("G"), &common::strategy2(2), 1);
    let hostile = "G\u{1b}]0;pwned\u{7}\u{1b}[2J\u{8}";
    let named = dir.join("named.csv");
    std::fs::write(&named, csv(&[(hostile, g)], true)).unwrap();
    let long = dir.join("long.csv");
    let field = format!("\u{1b}[31m{}", "9".repeat(2_000_000));
    std::fs::write(
        &long,
        format!("theta_i,theta_r,radiance_factor\n20,0,0.5\n20,5,{field}x\n"),
    )
    .unwrap();
    let header = dir.join("header.csv");
    let column = format!("\u{1b}[1m{}", "c".repeat(100_000));
    std::fs::write(
        &header,
        format!("theta_i,theta_r,radiance_factor,{column},{column}\n20,0,0.5,1,1\n"),
    )
    .unwrap();
    let out = gonio()
        .arg("fit")
        .args([&named, &long, &header])
        .output()
        .expect("run gonio fit");
    let (stdout, stderr) = (out.stdout.as_slice(), out.stderr.as_slice());
    for (what, bytes) in [("stdout", stdout), ("stderr", stderr)] {
        let text = String::from_utf8_lossy(bytes);
        assert!(
            !bytes.iter().any(|&b| b == 0x1b || b == 0x07 || b == 0x08),
            "{what} holds control bytes: {text:?}"
        );
    }
    let stdout = String::from_utf8_lossy(stdout);
    let stderr = String::from_utf8_lossy(stderr);
    // The sample's table, its name shown escaped.
    assert!(stdout.contains(r"G\u{1b}]0;pwned\u{7}"), "{stdout}");
    // Each bad field named at its line, quoted by a short prefix.
    assert!(
        stderr.contains("long.csv:3") && stderr.contains('…'),
        "{stderr}"
    );
    assert!(stderr.contains("header.csv:1"), "{stderr}");
    assert!(stderr.len() < 2_000, "{} bytes of errors", stderr.len());
    let _ = std::fs::remove_dir_all(&dir);
}
