//! Export of measured readings as CSV in the spirit of ASTM E1392 (standard practice for
//! angle-resolved optical scatter measurements on specular or diffuse surfaces): a header
//! naming the sample, instrument, date, wavelength, quantity and angle convention, then one
//! row per geometry with incidence and scatter angles (θ, φ) and the BRDF.
//!
//! Our readings lie in the specular plane: the source at (θi, φi = 0°), the detector at
//! (θs = θr, φs = 180°). A negative θr (detector past the normal, on the source's side) is
//! written as θs = |θr| at φs = 0°, so every row keeps θs ≥ 0 as E1392 has it.
//! BRDF [1/sr] = radiance factor / π (a perfect diffuser has radiance factor 1, BRDF 1/π).
use crate::analysis::fit::Observation;
use std::fmt::Write as _;
use std::path::Path;
use std::time::{SystemTime, UNIX_EPOCH};

/// The column header line.
pub const ASTM_E1392_COLUMNS: &str = "theta_i_deg,phi_i_deg,theta_s_deg,phi_s_deg,brdf_per_sr,radiance_factor,std_radiance_factor";

/// Write the readings of `sample` to `path` as an ASTM E1392-style CSV dated now (UTC).
pub fn write_astm_e1392_csv(path: &Path, sample: &str, instrument: &str, points: &[Observation]) -> std::io::Result<()> {
    std::fs::write(path, astm_e1392_csv(sample, instrument, SystemTime::now(), points))
}

/// The CSV text: `# key: value` header lines, the column line, one row per reading.
/// Numbers are written in Rust's shortest round-trip form, so reading them back gives the
/// same f64; an unknown uncertainty is an empty field.
pub fn astm_e1392_csv(sample: &str, instrument: &str, measured_at: SystemTime, points: &[Observation]) -> String {
    let mut s = String::new();
    let header: [(&str, String); 9] = [
        ("format", "angle-resolved scatter data after ASTM E1392, written by gonio".to_string()),
        ("sample", one_line(sample)),
        ("instrument", one_line(instrument)),
        ("date", iso8601_utc(measured_at)),
        ("wavelength", "photopic V(λ)".to_string()),
        ("quantity", "radiance factor (BRDF × π); brdf_per_sr = radiance_factor / π".to_string()),
        (
            "angles",
            "degrees from the surface normal; specular plane: incidence at phi_i = 0°, scatter at phi_s = 180° (phi_s = 0° when the detector is on the source's side)"
                .to_string(),
        ),
        ("std_radiance_factor", "standard uncertainty of the radiance factor; empty when not known".to_string()),
        ("points", points.len().to_string()),
    ];
    for (key, value) in header {
        // Writing to a String cannot fail.
        let _ = writeln!(s, "# {key}: {value}");
    }
    s += ASTM_E1392_COLUMNS;
    s += "\n";
    for o in points {
        let (theta_s_deg, phi_s_deg) = if o.theta_r_deg < 0.0 { (-o.theta_r_deg, 0.0) } else { (o.theta_r_deg, 180.0) };
        let brdf_per_sr = o.radiance_factor / std::f64::consts::PI;
        let std = o.std.map_or_else(String::new, |v| v.to_string());
        let _ = writeln!(s, "{},{},{},{},{},{},{}", o.theta_i_deg, 0.0, theta_s_deg, phi_s_deg, brdf_per_sr, o.radiance_factor, std);
    }
    s
}

/// A header value on one line: line breaks would end the `# key: value` line early.
fn one_line(text: &str) -> String {
    text.replace(['\r', '\n'], " ")
}

/// `YYYY-MM-DDThh:mm:ssZ` of a time (UTC; times before 1970 are written as 1970-01-01).
pub fn iso8601_utc(t: SystemTime) -> String {
    let secs = t.duration_since(UNIX_EPOCH).map_or(0, |d| d.as_secs());
    let days = (secs / 86_400) as i64;
    let rem = secs % 86_400;
    let (year, month, day) = civil_from_days(days);
    format!("{year:04}-{month:02}-{day:02}T{:02}:{:02}:{:02}Z", rem / 3600, rem % 3600 / 60, rem % 60)
}

/// Proleptic Gregorian (year, month, day) of a day count since 1970-01-01
/// (H. Hinnant's `civil_from_days`), to avoid a date-time crate for one header line.
fn civil_from_days(days: i64) -> (i64, u32, u32) {
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let month = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    let year = yoe + era * 400 + i64::from(month <= 2);
    (year, month, day)
}
