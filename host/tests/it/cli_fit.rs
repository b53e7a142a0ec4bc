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

/// `gonio fit --json` of one file: exit code, JSON lines, standard error.
fn fit_one(path: &std::path::Path) -> (Option<i32>, Vec<serde_json::Value>, String) {
    let out = gonio()
        .args(["fit", "--json"])
        .arg(path)
        .output()
        .expect("run gonio");
    let lines = String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).expect("JSON"))
        .collect();
    (
        out.status.code(),
        lines,
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// A table written as a spreadsheet in a European locale writes it (semicolons and
/// decimal commas; tabs and decimal commas; with a byte-order mark and quoted fields) is
/// read as the comma-separated one: the same fit to the last digit, over several seeds.
/// Headers with units (`theta_i_deg`) read as the bare names.
#[test]
fn semicolon_tab_and_decimal_comma_dialects_fit_as_the_comma_separated_table() {
    let dir = temp_dir("dialects");
    for seed in 1..=3 {
        let obs = common::noisy(&common::reference("SG"), &common::strategy2(2), seed);
        let std = |o: &host::analysis::fit::Observation| 0.01 * o.radiance_factor + 0.003;
        let comma: String = std::iter::once("theta_i,theta_r,radiance_factor,std\n".to_string())
            .chain(obs.iter().map(|o| {
                format!(
                    "{},{},{},{}\n",
                    o.theta_i_deg,
                    o.theta_r_deg,
                    o.radiance_factor,
                    std(o)
                )
            }))
            .collect();
        let european = |sep: &str, quote: bool| -> String {
            let q = |x: f64| {
                let t = x.to_string().replace('.', ",");
                if quote { format!("\"{t}\"") } else { t }
            };
            std::iter::once(format!(
                "\u{feff}theta_i_deg{sep}theta_r_deg{sep}radiance_factor{sep}std\r\n"
            ))
            .chain(obs.iter().map(|o| {
                format!(
                    "{}{sep}{}{sep}{}{sep}{}\r\n",
                    q(o.theta_i_deg),
                    q(o.theta_r_deg),
                    q(o.radiance_factor),
                    q(std(o))
                )
            }))
            .collect()
        };
        let files = [
            ("comma.csv", comma),
            ("semicolon.csv", european(";", false)),
            ("quoted.csv", european(";", true)),
            ("tabs.tsv", european("\t", false)),
        ];
        let mut sigmas = Vec::new();
        for (name, text) in &files {
            let path = dir.join(name);
            std::fs::write(&path, text).unwrap();
            let (code, lines, err) = fit_one(&path);
            assert!(code.is_some_and(|c| c == 0 || c == 3), "{name}: {err}");
            assert_eq!(lines.len(), 1, "{name}: {err}");
            assert_eq!(lines[0]["n"], obs.len(), "{name}");
            sigmas.push((lines[0]["sigma_deg"].clone(), lines[0]["rho_d"].clone()));
        }
        assert!(
            sigmas.iter().all(|s| *s == sigmas[0]),
            "seed {seed}: {sigmas:?}"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// A header gonio cannot read is refused naming what it found: its columns and the
/// separator they were split by.
#[test]
fn a_header_that_names_no_known_column_is_refused_with_what_was_found() {
    let dir = temp_dir("header");
    for (name, text, found) in [
        (
            "angles.csv",
            "angle;reflectance;x\n20;0,5;1\n",
            "3 columns 'angle', 'reflectance', 'x' separated by ';'",
        ),
        ("one.csv", "ti tr rf\n20 0 0.5\n", "one column 'ti tr rf'"),
        (
            "comma.csv",
            "theta_i,theta_r,value\n20,0,0.5\n",
            "'theta_i', 'theta_r', 'value' separated by ','",
        ),
    ] {
        let path = dir.join(name);
        std::fs::write(&path, text).unwrap();
        let (code, _, err) = fit_one(&path);
        assert_eq!(code, Some(1), "{name}: {err}");
        assert!(err.contains(&format!("{name}:1:")), "{name}: {err}");
        assert!(err.contains(found), "{name}: {err}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// gonio's own `.astm` export is read back: angles from radians, BRDF back to radiance
/// factor, the sample's name from its header; its fit is the CSV's (without
/// uncertainties, the noise from the residuals, as the export carries none).
#[test]
fn gonio_fit_reads_gonios_own_astm_export() {
    let dir = temp_dir("astm");
    for seed in 1..=3 {
        let obs = common::noisy(&common::reference("MC"), &common::strategy1_m12(), seed);
        let meta = host::output::export::AstmMetadata {
            sample: "MC sheet 4".into(),
            instrument: "test".into(),
            measured_at: std::time::UNIX_EPOCH,
            acceptance_deg: 1.0,
            integration_ms: 100,
            white_radiance_factor: 0.98,
            white_relative_uncertainty: 0.005,
            white_certificate: None,
        };
        let astm = dir.join("export.astm");
        std::fs::write(&astm, host::output::export::astm(&meta, &obs)).unwrap();
        let csv_path = dir.join("same.csv");
        std::fs::write(&csv_path, csv(&[("x", obs.clone())], false)).unwrap();
        let (code, lines, err) = fit_one(&astm);
        assert!(code.is_some_and(|c| c == 0 || c == 3), "{err}");
        assert_eq!(lines[0]["sample"], "MC sheet 4");
        assert_eq!(lines[0]["n"], obs.len());
        let (_, from_csv, _) = fit_one(&csv_path);
        for key in ["sigma_deg", "rho_s", "rho_d"] {
            let (a, b) = (
                lines[0][key].as_f64().unwrap(),
                from_csv[0][key].as_f64().unwrap(),
            );
            assert!(
                (a - b).abs() <= 1e-6 * b.abs(),
                "seed {seed}: {key} {a} against {b}"
            );
        }
    }
    // A row out of the specular plane, and a count that is not the rows': refused at
    // their line.
    let text = std::fs::read_to_string(dir.join("export.astm")).unwrap();
    let vars = text.lines().position(|l| l.starts_with("VARS")).unwrap();
    let mut rows: Vec<String> = text.lines().map(String::from).collect();
    rows[vars + 2] = "0.3,0,0.4,1.2,0.1".into();
    std::fs::write(dir.join("plane.astm"), rows.join("\n")).unwrap();
    let (code, _, err) = fit_one(&dir.join("plane.astm"));
    assert_eq!(code, Some(1));
    assert!(
        err.contains(&format!("plane.astm:{}:", vars + 3)) && err.contains("specular plane"),
        "{err}"
    );
    let cut: Vec<&str> = text.lines().take(vars + 4).collect();
    std::fs::write(dir.join("cut.astm"), cut.join("\n")).unwrap();
    let (code, _, err) = fit_one(&dir.join("cut.astm"));
    assert_eq!(code, Some(1));
    assert!(err.contains("NUM_POINTS"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Plausibility: a table in percent (×100) and one with angles in radians are flagged
/// `implausible-input` (exit 3) with a note saying what looks wrong and no class; the same
/// tables in fractions and degrees are not. Several papers and seeds.
#[test]
fn percent_and_radians_are_flagged_with_what_looks_wrong() {
    let dir = temp_dir("plausible");
    for (paper, seed) in [("G", 1), ("SG", 2), ("PPC", 3), ("MC", 4), ("J1", 5)] {
        let obs = common::noisy(&common::reference(paper), &common::full_grid(), seed);
        let scaled =
            |f: &dyn Fn(&host::analysis::fit::Observation) -> host::analysis::fit::Observation| {
                obs.iter().map(f).collect::<Vec<_>>()
            };
        let percent = scaled(&|o| host::analysis::fit::Observation {
            radiance_factor: o.radiance_factor * 100.0,
            ..*o
        });
        let radians = scaled(&|o| host::analysis::fit::Observation {
            theta_i_deg: o.theta_i_deg.to_radians(),
            theta_r_deg: o.theta_r_deg.to_radians(),
            ..*o
        });
        let notes_of = |line: &serde_json::Value| -> Vec<String> {
            line["notes"]
                .as_array()
                .unwrap()
                .iter()
                .map(|n| n["kind"].as_str().unwrap().to_string())
                .collect()
        };
        for (name, table, note) in [
            ("fractions", &obs, None),
            ("percent", &percent, Some("percent_suspected")),
            ("radians", &radians, Some("radians_suspected")),
        ] {
            let path = dir.join(format!("{paper}-{name}.csv"));
            std::fs::write(&path, csv(&[("x", table.clone())], false)).unwrap();
            let (code, lines, err) = fit_one(&path);
            assert_eq!(lines.len(), 1, "{paper} {name}: {err}");
            let flagged = lines[0]["flags"]
                .as_array()
                .unwrap()
                .iter()
                .any(|f| f == "implausible-input");
            let notes = notes_of(&lines[0]);
            match note {
                None => assert!(!flagged, "{paper} {name}: {notes:?}"),
                Some(note) => {
                    assert!(
                        flagged && notes.iter().any(|n| n == note),
                        "{paper} {name}: {notes:?}"
                    );
                    assert_eq!(code, Some(3), "{paper} {name}");
                    // No class from it: a flag beside a confident class is a guess
                    // read as an answer.
                    assert!(lines[0]["class"].is_null(), "{paper} {name}");
                    assert!(lines[0]["class_confidence"].is_null(), "{paper} {name}");
                    assert!(
                        lines[0]["class_undecided"]
                            .as_str()
                            .is_some_and(|w| w.contains("implausible-input")),
                        "{paper} {name}: {}",
                        lines[0]
                    );
                }
            }
        }
        // The table says what looks wrong in words.
        let out = gonio()
            .args(["fit"])
            .arg(dir.join(format!("{paper}-percent.csv")))
            .output()
            .unwrap();
        let text = String::from_utf8_lossy(&out.stdout);
        assert!(
            text.contains("percent") && text.contains("divide the table by 100"),
            "{text}"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// `--model paper` fits the paper's model alone (no extension step in the result),
/// `--model extended` tests the extensions (every term's test in the result), and a model
/// gonio does not know is a usage error naming the choices.
#[test]
fn the_model_is_chosen_on_the_command_line() {
    let dir = temp_dir("model-choice");
    let g = common::noisy(&common::reference("G"), &common::strategy2(2), 7);
    let path = dir.join("g.csv");
    std::fs::write(&path, csv(&[("x", g)], false)).expect("write");
    let run = |model: &str| -> serde_json::Value {
        let out = gonio()
            .args([
                "fit",
                "--json",
                "--model",
                model,
                path.to_str().expect("utf-8"),
            ])
            .output()
            .expect("run gonio");
        let stdout = String::from_utf8_lossy(&out.stdout);
        serde_json::from_str(stdout.lines().next().unwrap_or_default()).unwrap_or_else(|e| {
            panic!("{e}: {stdout} {}", String::from_utf8_lossy(&out.stderr));
        })
    };
    let extension = |v: &serde_json::Value| {
        v.pointer("/fit/model_extension")
            .or_else(|| v.get("model_extension"))
            .cloned()
            .unwrap_or_else(|| panic!("no model_extension in {v}"))
    };
    let paper = run("paper");
    assert!(extension(&paper).is_null(), "{paper}");
    let extended = run("extended");
    assert!(extension(&extended)["tests"].is_array(), "{extended}");
    let out = gonio()
        .args(["fit", "--model", "haze", path.to_str().expect("utf-8")])
        .output()
        .expect("run gonio");
    assert_eq!(out.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("extended") && stderr.contains("paper"),
        "{stderr}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
