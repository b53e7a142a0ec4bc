//! Export of measured readings in the ASTM E1392 / E2387 exchange format that BRDF tools
//! read (libbsdf's and ALTA's ASTM readers): header lines of a keyword and its value, a
//! `NUM_POINTS n` line, a `VARS theta_i,phi_i,theta_s,phi_s,BRDF` line that ends the
//! header, then one comma-separated row per geometry: the angles in radians and the BRDF
//! in sr⁻¹.
//!
//! Our readings lie in the specular plane: the source at (θi, φi = 0), the detector at
//! (θs = θr, φs = π). A negative θr (detector past the normal, on the source's side) is
//! written as θs = |θr| at φs = 0, so every row keeps θs ≥ 0.
//! BRDF [1/sr] = radiance factor / π (a perfect diffuser has radiance factor 1, BRDF 1/π).
//! The readings' own uncertainties are in `readings.csv` (a fifth column would read as a
//! second colour channel); the calibration's are in `session.json`.
use crate::analysis::fit::Observation;
use std::fmt::Write as _;
use std::time::{SystemTime, UNIX_EPOCH};

/// The `VARS` line's columns.
pub(crate) const ASTM_VARS: &str = "theta_i,phi_i,theta_s,phi_s,BRDF";

/// What an export says about the measurement besides the readings.
#[derive(Clone, Debug, PartialEq)]
pub struct AstmMetadata {
    /// The sample's name.
    pub sample: String,
    /// The instrument (board, firmware, serial number).
    pub instrument: String,
    /// When it was measured.
    pub measured_at: SystemTime,
    /// The detector's full angular acceptance, degrees.
    pub acceptance_deg: f64,
    /// Integration time of every reading, ms.
    pub integration_ms: u16,
    /// The white standard's certified radiance factor.
    pub white_radiance_factor: f64,
    /// Its relative standard uncertainty (k = 1).
    pub white_relative_uncertainty: f64,
    /// The certificate those values come from, when one was given.
    pub white_certificate: Option<crate::instrument::calibration::TileCertificate>,
}

/// The solid angle of a circular acceptance of full width `acceptance_deg`, sr.
pub(crate) fn acceptance_solid_angle_sr(acceptance_deg: f64) -> f64 {
    2.0 * std::f64::consts::PI * (1.0 - (0.5 * acceptance_deg.to_radians()).cos())
}

/// The file name of a sample's export: `<sample>.astm` (the sample as a file name).
pub(crate) fn astm_file_name(sample: &str) -> String {
    format!("{}.astm", crate::output::folder::file_name_of(sample))
}

/// A header value as whitespace-separated words on one line; a word a reader would take
/// for `NUM_POINTS` or `VARS` is written with a leading `_`.
fn header_value(text: &str) -> String {
    let words: Vec<String> = text
        .split_whitespace()
        .map(|w| {
            if w == "NUM_POINTS" || w == "VARS" {
                format!("_{w}")
            } else {
                w.to_string()
            }
        })
        .collect();
    if words.is_empty() {
        "-".to_string()
    } else {
        words.join(" ")
    }
}

/// The `.astm` text. Numbers are written in Rust's shortest round-trip form, so reading
/// them back gives the same f64.
pub fn astm(meta: &AstmMetadata, points: &[Observation]) -> String {
    let mut s = String::new();
    let certificate = meta.white_certificate.as_ref().map_or_else(
        || "none given (the tile's values were entered or are the defaults)".to_string(),
        |c| {
            format!(
                "tile {}, certificate {}{}, issued {}{}, expanded uncertainty {} at k = {}",
                c.tile,
                c.certificate,
                c.issued_by
                    .as_ref()
                    .map_or_else(String::new, |by| format!(" by {by}")),
                c.issued,
                c.valid_until
                    .as_ref()
                    .map_or_else(String::new, |u| format!(", valid until {u}")),
                c.expanded_uncertainty,
                c.coverage_factor
            )
        },
    );
    let header: [(&str, String); 13] = [
        ("SOURCE", format!("gonio {}", env!("CARGO_PKG_VERSION"))),
        ("SAMPLE_NAME", meta.sample.clone()),
        ("INSTRUMENT", meta.instrument.clone()),
        ("DATE", iso8601_utc(meta.measured_at)),
        ("TYPE", "BRDF in the specular plane, sr^-1 (radiance factor / pi)".to_string()),
        ("WAVELENGTH", "photopic V(lambda), white LED".to_string()),
        ("ANGLES", "radians from the surface normal; source at phi_i = 0, detector at phi_s = pi (0 on the source's side)".to_string()),
        ("ACCEPTANCE_FULL_WIDTH_DEG", meta.acceptance_deg.to_string()),
        ("SOLID_ANGLE_SR", acceptance_solid_angle_sr(meta.acceptance_deg).to_string()),
        ("INTEGRATION_MS", meta.integration_ms.to_string()),
        ("WHITE_STANDARD_RADIANCE_FACTOR", meta.white_radiance_factor.to_string()),
        ("WHITE_STANDARD_RELATIVE_UNCERTAINTY", meta.white_relative_uncertainty.to_string()),
        ("WHITE_STANDARD_CERTIFICATE", certificate),
    ];
    for (key, value) in header {
        // Writing to a String cannot fail.
        let _ = writeln!(s, "{key} {}", header_value(&value));
    }
    let _ = writeln!(s, "NUM_POINTS {}", points.len());
    let _ = writeln!(s, "VARS {ASTM_VARS}");
    for o in points {
        let (theta_s_deg, phi_s) = if o.theta_r_deg < 0.0 {
            (-o.theta_r_deg, 0.0)
        } else {
            (o.theta_r_deg, std::f64::consts::PI)
        };
        let brdf_per_sr = o.radiance_factor / std::f64::consts::PI;
        let _ = writeln!(
            s,
            "{},{},{},{},{}",
            o.theta_i_deg.to_radians(),
            0.0,
            theta_s_deg.to_radians(),
            phi_s,
            brdf_per_sr
        );
    }
    s
}

/// `YYYY-MM-DDThh:mm:ssZ` of a time (UTC; times before 1970 are written as 1970-01-01).
pub fn iso8601_utc(t: SystemTime) -> String {
    let secs = t.duration_since(UNIX_EPOCH).map_or(0, |d| d.as_secs());
    chrono::DateTime::from_timestamp(i64::try_from(secs).unwrap_or(i64::MAX), 0)
        .unwrap_or_default()
        .format("%Y-%m-%dT%H:%M:%SZ")
        .to_string()
}
