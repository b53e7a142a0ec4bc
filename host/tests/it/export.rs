//! The `.astm` export (ASTM E1392 / E2387 exchange format), read back by a reader written
//! here from the format's description (header keyword lines, `NUM_POINTS n`, a `VARS` line
//! of comma-separated column names ending the header, then comma-separated rows of
//! θi, φi, θs, φs in radians and the BRDF in sr⁻¹), not from the writer: the angle
//! convention, BRDF = radiance factor / π, numbers that read back exactly, the metadata,
//! and a session folder's export against its readings.csv.
use crate::cli_support;
use host::analysis::fit::Observation;
use host::output::export::{self, AstmMetadata};
use std::collections::HashMap;
use std::f64::consts::PI;
use std::time::{Duration, UNIX_EPOCH};

fn readings() -> Vec<Observation> {
    vec![
        Observation {
            theta_i_deg: 20.0,
            theta_r_deg: 0.0,
            radiance_factor: 0.8612345678901234,
            std: Some(0.0091),
            theta_r_span_deg: 0.0,
        },
        Observation {
            theta_i_deg: 20.0,
            theta_r_deg: 20.0,
            radiance_factor: 9.123456789,
            std: None,
            theta_r_span_deg: 0.0,
        },
        Observation {
            theta_i_deg: 45.0,
            theta_r_deg: 44.75,
            radiance_factor: 31.4159,
            std: Some(0.31),
            theta_r_span_deg: 0.0,
        },
        Observation {
            theta_i_deg: 60.0,
            theta_r_deg: 70.0,
            radiance_factor: 1e-3 / 3.0,
            std: Some(0.003),
            theta_r_span_deg: 0.0,
        },
        Observation {
            theta_i_deg: 30.0,
            theta_r_deg: -0.5,
            radiance_factor: 0.5,
            std: None,
            theta_r_span_deg: 0.0,
        },
    ]
}

fn meta(sample: &str) -> AstmMetadata {
    AstmMetadata {
        sample: sample.to_string(),
        instrument: "gonio STM32F411 serial SIM-0001".into(),
        measured_at: UNIX_EPOCH + Duration::from_secs(1_764_000_000),
        acceptance_deg: 1.0,
        integration_ms: 100,
        white_radiance_factor: 0.987,
        white_relative_uncertainty: 0.004,
        white_certificate: None,
    }
}

/// An ASTM file as a reader of the format sees it.
struct AstmFile {
    keywords: HashMap<String, String>,
    num_points: usize,
    vars: Vec<String>,
    rows: Vec<Vec<f64>>,
}

fn read_astm(text: &str) -> AstmFile {
    let mut keywords = HashMap::new();
    let mut num_points = None;
    let mut vars = None;
    let mut lines = text.lines();
    for line in lines.by_ref() {
        let (key, value) = line.split_once(' ').unwrap_or((line, ""));
        match key {
            "NUM_POINTS" => {
                num_points = Some(
                    value
                        .trim()
                        .parse::<usize>()
                        .expect("NUM_POINTS is a count"),
                )
            }
            "VARS" => {
                vars = Some(
                    value
                        .split(',')
                        .map(|v| v.trim().to_string())
                        .collect::<Vec<_>>(),
                );
                break;
            }
            _ => {
                assert!(!key.is_empty(), "an empty header line");
                keywords.insert(key.to_string(), value.to_string());
            }
        }
    }
    let vars = vars.expect("a VARS line ends the header");
    let rows: Vec<Vec<f64>> = lines
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            l.split(',')
                .map(|f| f.trim().parse::<f64>().expect("a number"))
                .collect()
        })
        .collect();
    AstmFile {
        keywords,
        num_points: num_points.expect("NUM_POINTS"),
        vars,
        rows,
    }
}

#[test]
fn an_astm_reader_gets_the_angles_in_radians_and_the_brdf() {
    let points = readings();
    let file = read_astm(&export::astm(&meta("sheet A7"), &points));
    assert_eq!(file.vars, ["theta_i", "phi_i", "theta_s", "phi_s", "BRDF"]);
    assert_eq!(file.num_points, points.len());
    assert_eq!(file.rows.len(), file.num_points, "NUM_POINTS rows");
    for (row, o) in file.rows.iter().zip(&points) {
        assert_eq!(row.len(), 5);
        let (ti, phi_i, ts, phi_s, brdf) = (row[0], row[1], row[2], row[3], row[4]);
        assert_eq!(ti, o.theta_i_deg.to_radians(), "radians, exactly");
        assert_eq!(phi_i, 0.0);
        // The detector's side of the normal decides φs; θs is never negative.
        if o.theta_r_deg >= 0.0 {
            assert_eq!((ts, phi_s), (o.theta_r_deg.to_radians(), PI));
        } else {
            assert_eq!((ts, phi_s), ((-o.theta_r_deg).to_radians(), 0.0));
        }
        assert!((0.0..=PI / 2.0).contains(&ti) && (0.0..=PI / 2.0).contains(&ts));
        assert!(
            (brdf * PI - o.radiance_factor).abs() <= 1e-15 * o.radiance_factor,
            "BRDF = R/π: {brdf}"
        );
    }
    let k = &file.keywords;
    assert_eq!(k["SAMPLE_NAME"], "sheet A7");
    assert_eq!(k["DATE"], "2025-11-24T16:00:00Z");
    assert_eq!(k["WHITE_STANDARD_RADIANCE_FACTOR"], "0.987");
    assert_eq!(k["WHITE_STANDARD_RELATIVE_UNCERTAINTY"], "0.004");
    assert_eq!(k["INTEGRATION_MS"], "100");
    let omega: f64 = k["SOLID_ANGLE_SR"].parse().unwrap();
    assert!((omega - 2.392_2e-4).abs() < 1e-7, "a 1° cone: {omega}");
    assert!(k["SOURCE"].starts_with("gonio "));
}

#[test]
fn a_header_value_cannot_end_the_header_or_break_a_line() {
    let file = read_astm(&export::astm(
        &meta("two\nlines VARS NUM_POINTS"),
        &readings(),
    ));
    assert_eq!(file.keywords["SAMPLE_NAME"], "two lines _VARS _NUM_POINTS");
    assert_eq!(file.num_points, 5);
    assert_eq!(file.rows.len(), 5);
    assert_eq!(
        read_astm(&export::astm(&meta("   "), &[])).keywords["SAMPLE_NAME"],
        "-"
    );
}

#[test]
fn dates_are_iso8601_utc() {
    let at = |secs: u64| export::iso8601_utc(UNIX_EPOCH + Duration::from_secs(secs));
    assert_eq!(at(0), "1970-01-01T00:00:00Z");
    assert_eq!(at(951_782_400), "2000-02-29T00:00:00Z");
    assert_eq!(at(1_709_251_199), "2024-02-29T23:59:59Z");
    assert_eq!(at(4_102_444_800), "2100-01-01T00:00:00Z");
}

/// A measured session's export holds its readings (as readings.csv has them) and its
/// calibration's white standard; readings.csv reads with a plain CSV reader.
#[test]
fn a_sessions_export_holds_its_readings_and_white_standard() {
    let dir = cli_support::temp_dir("export", "session");
    let out = cli_support::gonio(&[
        "measure",
        "--sim",
        "SG",
        "--spots",
        "1",
        "--tile-radiance-factor",
        "0.97",
        "--tile-uncertainty-pct",
        "0.3",
        "--out",
        dir.to_str().unwrap(),
    ]);
    // Clean or flagged (its seed drawn for the run): the export is written either way.
    cli_support::assert_finished(&out);
    let file = read_astm(&std::fs::read_to_string(dir.join("SG.astm")).expect("SG.astm"));
    assert_eq!(file.keywords["WHITE_STANDARD_RADIANCE_FACTOR"], "0.97");
    assert_eq!(
        file.keywords["WHITE_STANDARD_RELATIVE_UNCERTAINTY"],
        "0.003"
    );
    assert!(file.keywords["INSTRUMENT"].contains("SIM-0001"));
    let csv = std::fs::read_to_string(dir.join("readings.csv")).unwrap();
    let mut lines = csv.lines();
    assert_eq!(
        lines.next(),
        Some("theta_i_deg,theta_r_deg,radiance_factor,std"),
        "one header line, the angles' unit in their names, then numbers"
    );
    let rows: Vec<Vec<f64>> = lines
        .map(|l| l.split(',').map(|f| f.parse().expect("a number")).collect())
        .collect();
    assert_eq!(rows.len(), file.num_points);
    for (csv_row, astm_row) in rows.iter().zip(&file.rows) {
        assert_eq!(astm_row[0], csv_row[0].to_radians());
        assert_eq!(astm_row[2], csv_row[1].abs().to_radians());
        assert!((astm_row[4] * PI - csv_row[2]).abs() <= 1e-14 * csv_row[2]);
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// A session calibrated with a tile certificate: its values are the calibration's, and the
/// certificate is named in calibration.json, the export and the report.
#[test]
fn a_tile_certificate_is_recorded_in_every_export() {
    let dir = cli_support::temp_dir("export", "certificate");
    std::fs::create_dir_all(&dir).unwrap();
    let certificate = dir.join("tile.json");
    let today = chrono::Local::now().date_naive();
    let issued = (today - chrono::Days::new(100)).to_string();
    std::fs::write(
        &certificate,
        format!(r#"{{"tile": "Ceramic tile #9", "certificate": "LAB-77", "issued_by": "a laboratory", "issued": "{issued}", "radiance_factor": 0.975, "expanded_uncertainty": 0.0078}}"#),
    )
    .unwrap();
    let session = dir.join("session");
    let out = cli_support::gonio(&[
        "measure",
        "--sim",
        "PPC",
        "--spots",
        "1",
        "--tile-certificate",
        certificate.to_str().unwrap(),
        "--out",
        session.to_str().unwrap(),
    ]);
    cli_support::assert_finished(&out);
    let file = read_astm(&std::fs::read_to_string(session.join("PPC.astm")).expect("PPC.astm"));
    assert_eq!(file.keywords["WHITE_STANDARD_RADIANCE_FACTOR"], "0.975");
    // 0.0078 at k = 2 over 0.975: 0.4 % standard.
    let u: f64 = file.keywords["WHITE_STANDARD_RELATIVE_UNCERTAINTY"]
        .parse()
        .unwrap();
    assert!((u - 0.004).abs() < 1e-12, "{u}");
    let named = &file.keywords["WHITE_STANDARD_CERTIFICATE"];
    assert!(
        named.contains("Ceramic tile #9")
            && named.contains("LAB-77")
            && named.contains(&issued)
            && named.contains("k = 2"),
        "{named}"
    );
    let calibration: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(session.join("calibration.json")).unwrap())
            .unwrap();
    assert_eq!(calibration["white_certificate"]["certificate"], "LAB-77");
    assert_eq!(
        calibration["white_certificate"]["file_sha256"]
            .as_str()
            .map(str::len),
        Some(64)
    );
    let report = std::fs::read_to_string(session.join("report.html")).unwrap();
    assert!(
        report.contains("certificate LAB-77") && report.contains("Ceramic tile #9"),
        "the report names the certificate"
    );
    // Without one, the export says so rather than leaving it out.
    let plain = dir.join("plain");
    cli_support::assert_finished(&cli_support::gonio(&[
        "measure",
        "--sim",
        "PPC",
        "--spots",
        "1",
        "--out",
        plain.to_str().unwrap(),
    ]));
    let file = read_astm(&std::fs::read_to_string(plain.join("PPC.astm")).unwrap());
    assert!(
        file.keywords["WHITE_STANDARD_CERTIFICATE"].starts_with("none given"),
        "{}",
        file.keywords["WHITE_STANDARD_CERTIFICATE"]
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// A sweep session's readings.csv: the angles' unit in the header (the bins' travel too)
/// and every angle as the instrument can mean it, to 0.0001° (no `0.09999999999999432`);
/// `gonio fit` reads it, and still reads the first version's file (unitless header,
/// unrounded angles).
#[test]
fn sweep_readings_have_units_in_their_header_and_no_float_noise() {
    let dir = cli_support::temp_dir("export", "sweep");
    let out = cli_support::gonio(&[
        "measure",
        "--sim",
        "G",
        "--policy",
        "sweep",
        "--spots",
        "1",
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert!(
        out.status.code().is_some_and(|c| c == 0 || c == 3),
        "{}",
        cli_support::stderr(&out)
    );
    let csv = std::fs::read_to_string(dir.join("readings.csv")).unwrap();
    let mut lines = csv.lines();
    assert_eq!(
        lines.next(),
        Some("theta_i_deg,theta_r_deg,radiance_factor,std,theta_r_span_deg")
    );
    let mut rows = 0;
    for line in lines {
        let fields: Vec<&str> = line.split(',').collect();
        for angle in [fields[0], fields[1], fields[4]] {
            let decimals = angle.split_once('.').map_or(0, |(_, d)| d.len());
            assert!(decimals <= 4, "'{angle}' in '{line}'");
            angle.parse::<f64>().expect("a number");
        }
        rows += 1;
    }
    assert!(rows > 100, "a sweep's bins: {rows}");
    for file in [
        dir.join("readings.csv"),
        std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data/v1-session-G/readings.csv"),
    ] {
        let out = cli_support::gonio(&["fit", "--json", file.to_str().unwrap()]);
        assert!(
            out.status.code().is_some_and(|c| c == 0 || c == 3),
            "{}: {}",
            file.display(),
            cli_support::stderr(&out)
        );
    }
    // The folder verifies: readings.csv is what points.jsonl says, in this form.
    let out = cli_support::gonio(&["verify", dir.to_str().unwrap()]);
    assert!(out.status.success(), "{}", cli_support::stderr(&out));
    let _ = std::fs::remove_dir_all(&dir);
}
