//! ASTM E1392-style CSV: the header, the angle convention, BRDF = radiance factor / π, and
//! numbers that read back exactly.
use host::output::export::{self, ASTM_E1392_COLUMNS};
use host::analysis::fit::Observation;
use std::collections::HashMap;
use std::time::{Duration, UNIX_EPOCH};

fn readings() -> Vec<Observation> {
    vec![
        Observation { theta_i_deg: 20.0, theta_r_deg: 0.0, radiance_factor: 0.8612345678901234, std: Some(0.0091) },
        Observation { theta_i_deg: 20.0, theta_r_deg: 20.0, radiance_factor: 9.123456789, std: None },
        Observation { theta_i_deg: 45.0, theta_r_deg: 44.75, radiance_factor: 31.4159, std: Some(0.31) },
        Observation { theta_i_deg: 60.0, theta_r_deg: 70.0, radiance_factor: 1e-3 / 3.0, std: Some(0.003) },
        Observation { theta_i_deg: 30.0, theta_r_deg: -0.5, radiance_factor: 0.5, std: None },
    ]
}

struct Parsed {
    header: HashMap<String, String>,
    rows: Vec<[Option<f64>; 7]>,
}

fn parse(text: &str) -> Parsed {
    let mut header = HashMap::new();
    let mut lines = text.lines();
    let mut columns = None;
    for line in lines.by_ref() {
        if let Some(rest) = line.strip_prefix("# ") {
            let (key, value) = rest.split_once(": ").expect("`# key: value`");
            header.insert(key.to_string(), value.to_string());
        } else {
            columns = Some(line);
            break;
        }
    }
    assert_eq!(columns, Some(ASTM_E1392_COLUMNS));
    let rows = lines
        .map(|line| {
            let fields: Vec<&str> = line.split(',').collect();
            assert_eq!(fields.len(), 7, "{line}");
            std::array::from_fn(|i| (!fields[i].is_empty()).then(|| fields[i].parse::<f64>().expect("a number")))
        })
        .collect();
    Parsed { header, rows }
}

#[test]
fn numbers_angles_and_brdf_round_trip() {
    let points = readings();
    let dir = std::env::temp_dir().join(format!("gonio-export-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let path = dir.join("sheet.csv");
    export::write_astm_e1392_csv(&path, "sheet A7", "gonio sim", &points).expect("written");
    let parsed = parse(&std::fs::read_to_string(&path).expect("read back"));

    assert_eq!(parsed.header["sample"], "sheet A7");
    assert_eq!(parsed.header["instrument"], "gonio sim");
    assert_eq!(parsed.header["wavelength"], "photopic V(λ)");
    assert!(parsed.header["quantity"].starts_with("radiance factor (BRDF × π)"));
    assert!(parsed.header["angles"].contains("phi_i = 0°") && parsed.header["angles"].contains("phi_s = 180°"));
    assert_eq!(parsed.header["points"], "5");
    let date = &parsed.header["date"];
    assert!(date.len() == 20 && date.ends_with('Z') && &date[10..11] == "T" && date.starts_with("20"), "ISO 8601 UTC: {date}");

    assert_eq!(parsed.rows.len(), points.len());
    for (row, o) in parsed.rows.iter().zip(&points) {
        let [ti, phi_i, ts, phi_s, brdf, rf, std] = *row;
        assert_eq!(ti, Some(o.theta_i_deg));
        assert_eq!(phi_i, Some(0.0));
        // The detector's side of the normal decides φs; θs is never negative.
        if o.theta_r_deg >= 0.0 {
            assert_eq!((ts, phi_s), (Some(o.theta_r_deg), Some(180.0)));
        } else {
            assert_eq!((ts, phi_s), (Some(-o.theta_r_deg), Some(0.0)));
        }
        assert_eq!(rf, Some(o.radiance_factor), "exact round trip");
        assert_eq!(std, o.std);
        let brdf = brdf.expect("brdf");
        assert!((brdf * std::f64::consts::PI - o.radiance_factor).abs() <= 1e-15 * o.radiance_factor, "BRDF = R/π");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn header_values_stay_on_one_line() {
    let text = export::astm_e1392_csv("two\nlines", "bench\r\n2", UNIX_EPOCH, &readings());
    let parsed = parse(&text);
    assert_eq!(parsed.header["sample"], "two lines");
    assert_eq!(parsed.header["instrument"], "bench  2");
    assert_eq!(parsed.header["date"], "1970-01-01T00:00:00Z");
}

#[test]
fn dates_are_iso8601_utc() {
    let at = |secs: u64| export::iso8601_utc(UNIX_EPOCH + Duration::from_secs(secs));
    assert_eq!(at(0), "1970-01-01T00:00:00Z");
    assert_eq!(at(951_782_400), "2000-02-29T00:00:00Z");
    assert_eq!(at(1_709_251_199), "2024-02-29T23:59:59Z");
    assert_eq!(at(4_102_444_800), "2100-01-01T00:00:00Z");
}

#[test]
fn unwritable_path_is_an_error() {
    let path = std::env::temp_dir().join(format!("gonio-export-missing-{}", std::process::id())).join("no/such/dir/x.csv");
    assert!(export::write_astm_e1392_csv(&path, "s", "i", &readings()).is_err());
}
