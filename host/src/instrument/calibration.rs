//! The calibration as the instrument takes it and keeps it: a tile certificate read from
//! its file, a calibration taken now or read from an earlier session's file and refused
//! when too old or from another instrument. The data and the maths are
//! [`crate::analysis::calibration`]'s, re-exported here.

pub use crate::analysis::calibration::{
    Calibration, CalibrationError, DEFAULT_TILE_RELATIVE_UNCERTAINTY,
    DEFAULT_WHITE_RADIANCE_FACTOR, GainRatio, Tile, TileCertificate, WhitePoint, pool,
};
use protocol::{DeviceInfo, Reading};
use std::path::Path;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

impl TileCertificate {
    /// Read and check a certificate file. `today` is the local date of the session: a
    /// certificate issued after it, or expired before it, is refused.
    pub fn read(
        path: &Path,
        today: chrono::NaiveDate,
    ) -> Result<TileCertificate, CalibrationError> {
        let bytes = std::fs::read(path).map_err(|e| {
            CalibrationError::BadTile(format!("{}: cannot read: {e}", path.display()))
        })?;
        TileCertificate::parse(path, &bytes, today)
    }

    /// Check the bytes of a certificate file as [`TileCertificate::read`] does (`path`
    /// names the file in messages): the reader without the file system, for the fuzz
    /// targets (host/fuzz).
    pub fn parse(
        path: &Path,
        bytes: &[u8],
        today: chrono::NaiveDate,
    ) -> Result<TileCertificate, CalibrationError> {
        let bad = |what: String| CalibrationError::BadTile(format!("{}: {what}", path.display()));
        let text = std::str::from_utf8(bytes).map_err(|_| bad("not UTF-8 text".into()))?;
        let mut certificate: TileCertificate =
            serde_json::from_str(text).map_err(|e| bad(format!("line {}: {e}", e.line())))?;
        if let Some(schema) = &certificate.schema
            && schema != crate::schema::TILE_CERTIFICATE
        {
            return Err(bad(format!(
                "schema '{schema}' is not '{}'",
                crate::schema::TILE_CERTIFICATE
            )));
        }
        certificate
            .validate(today)
            .map_err(|e| bad(e.to_string()))?;
        // The values as the tile they give, checked here to name the file.
        if let Err(CalibrationError::BadTile(what)) = certificate.clone().tile() {
            return Err(bad(what));
        }
        use sha2::Digest as _;
        certificate.file_sha256 = Some(
            sha2::Sha256::digest(bytes)
                .iter()
                .map(|b| format!("{b:02x}"))
                .collect(),
        );
        certificate.schema = Some(crate::schema::TILE_CERTIFICATE.into());
        Ok(certificate)
    }
}

/// The instrument's identity as a calibration records it.
pub(crate) fn instrument_name(info: &DeviceInfo) -> String {
    format!("{} (firmware {})", info.board, info.firmware_version)
}

/// Seconds since the Unix epoch now.
pub(crate) fn unix_now_s() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_secs())
}

impl Calibration {
    /// A calibration taken now from its readings, with the tile's certificate and the
    /// nominal gains of the handshake; no gain ratio calibrated yet.
    pub fn new(
        instrument: String,
        tile: Tile,
        relative_gains: Vec<f64>,
        dark: Vec<Reading>,
        white: Vec<WhitePoint>,
    ) -> Calibration {
        Calibration::taken_at(unix_now_s(), instrument, tile, relative_gains, dark, white)
    }

    /// Read a calibration saved by an earlier session (its `calibration.json`, or the
    /// `session.json` that holds one), refusing it when older than `max_age` or taken on
    /// another instrument.
    pub fn load(
        path: &Path,
        max_age: Duration,
        info: &DeviceInfo,
    ) -> Result<Calibration, CalibrationError> {
        let unreadable = |why: String| CalibrationError::Unreadable {
            path: path.display().to_string(),
            why,
        };
        let text = std::fs::read_to_string(path).map_err(|e| unreadable(e.to_string()))?;
        let value: serde_json::Value =
            serde_json::from_str(&text).map_err(|e| unreadable(e.to_string()))?;
        // A session's document holds the calibration it was converted with.
        let calibration = match value.get("calibration") {
            Some(inner) => serde_json::from_value(inner.clone())
                .map_err(|e| unreadable(format!("calibration: {e}")))?,
            None => Calibration::from_document(value).map_err(|e| unreadable(e.to_string()))?,
        };
        // What the file holds must be usable before its age and instrument are looked at.
        calibration
            .validate()
            .map_err(|e| unreadable(e.to_string()))?;
        calibration.check(&path.display().to_string(), max_age, info)?;
        Ok(calibration)
    }

    /// Refuse this calibration (from `path`, for messages) when older than `max_age` or
    /// taken on another instrument than `info`'s.
    pub fn check(
        &self,
        path: &str,
        max_age: Duration,
        info: &DeviceInfo,
    ) -> Result<(), CalibrationError> {
        let age = self.age(unix_now_s());
        if age > max_age {
            return Err(CalibrationError::Stale {
                path: path.to_string(),
                age_h: age.as_secs_f64() / 3600.0,
                max_h: max_age.as_secs_f64() / 3600.0,
            });
        }
        let this = instrument_name(info);
        if self.instrument != this {
            return Err(CalibrationError::OtherInstrument {
                path: path.to_string(),
                taken_on: self.instrument.clone(),
                this,
            });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::analysis::calibration::tests::reading;

    fn calibration() -> Calibration {
        Calibration::new(
            "test".into(),
            Tile::default(),
            vec![1.0, 0.1, 0.01],
            vec![reading(200.0, 0), reading(200.0, 1), reading(200.0, 2)],
            vec![WhitePoint {
                theta_i_deg: 20.0,
                reading: reading(26_200.0, 0),
            }],
        )
    }

    fn certificate_file(text: &str) -> (tempfile::TempDir, std::path::PathBuf) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("tile.json");
        std::fs::write(&path, text).unwrap();
        (dir, path)
    }

    const CERTIFICATE: &str = r#"{"tile": "PTFE #7", "certificate": "C-1", "issued": "2026-03-01", "valid_until": "2027-03-01",
        "radiance_factor": 0.98, "expanded_uncertainty": 0.0098, "coverage_factor": 2}"#;

    fn day(text: &str) -> chrono::NaiveDate {
        chrono::NaiveDate::parse_from_str(text, "%Y-%m-%d").unwrap()
    }

    #[test]
    fn a_tile_certificate_gives_the_tile_and_is_recorded_with_its_file_hash() {
        let (_dir, path) = certificate_file(CERTIFICATE);
        let tile = TileCertificate::read(&path, day("2026-12-02"))
            .and_then(TileCertificate::tile)
            .expect("a good certificate");
        assert_eq!(tile.radiance_factor, 0.98);
        // Expanded 0.0098 at k = 2 over 0.98: 0.5 % standard.
        assert!(
            (tile.relative_uncertainty - 0.005).abs() < 1e-15,
            "{}",
            tile.relative_uncertainty
        );
        let certificate = tile.certificate.clone().expect("recorded");
        use sha2::Digest as _;
        let sha: String = sha2::Sha256::digest(CERTIFICATE.as_bytes())
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect();
        assert_eq!(certificate.file_sha256.as_deref(), Some(sha.as_str()));
        let c = Calibration::new(
            "test".into(),
            tile,
            vec![1.0],
            vec![reading(200.0, 0)],
            vec![],
        );
        let back = Calibration::from_document(c.to_document().unwrap()).unwrap();
        assert_eq!(back.white_certificate, Some(certificate));
        assert_eq!(
            back.tile(),
            c.tile(),
            "the tile read back is the one calibrated with"
        );
        // Without k, it is 2.
        let (_dir, path) = certificate_file(&CERTIFICATE.replace(r#", "coverage_factor": 2"#, ""));
        assert_eq!(
            TileCertificate::read(&path, day("2026-12-02"))
                .unwrap()
                .coverage_factor,
            2.0
        );
    }

    #[test]
    fn a_bad_tile_certificate_is_refused_naming_the_file_and_what_is_wrong() {
        let cases: [(String, &str, &str); 10] = [
            (
                CERTIFICATE.to_string(),
                "2027-03-02",
                "expired on 2027-03-01",
            ),
            (CERTIFICATE.to_string(), "2026-02-28", "after today"),
            (
                CERTIFICATE.replace("2026-03-01\"", "01/03/2026\""),
                "2026-12-02",
                "'issued' must be a date YYYY-MM-DD",
            ),
            (
                CERTIFICATE.replace("\"coverage_factor\": 2", "\"coverage_factor\": 0.5"),
                "2026-12-02",
                "'coverage_factor' must be between 1 and 4",
            ),
            (
                CERTIFICATE.replace("0.0098", "-0.01"),
                "2026-12-02",
                "'expanded_uncertainty' must be a number at least 0",
            ),
            (
                CERTIFICATE.replace("\"radiance_factor\": 0.98", "\"radiance_factor\": 1.98"),
                "2026-12-02",
                "radiance factor 1.98 is not in (0, 1.2]",
            ),
            (
                CERTIFICATE.replace("0.0098", "1.2"),
                "2026-12-02",
                "is not in [0, 50) %",
            ),
            (
                CERTIFICATE.replace("\"tile\"", "\"colour\": \"white\", \"tile\""),
                "2026-12-02",
                "unknown field `colour`",
            ),
            (
                CERTIFICATE.replace("\"PTFE #7\"", "\"\""),
                "2026-12-02",
                "'tile' must be a name",
            ),
            (
                CERTIFICATE.replacen('{', "{\"schema\": \"gonio-tile-certificate/9\", ", 1),
                "2026-12-02",
                "schema 'gonio-tile-certificate/9'",
            ),
        ];
        for (text, today, expected) in cases {
            let (_dir, path) = certificate_file(&text);
            let err = TileCertificate::read(&path, day(today))
                .and_then(TileCertificate::tile)
                .expect_err(expected)
                .to_string();
            assert!(
                err.contains(expected) && err.contains("tile.json"),
                "{expected}: {err}"
            );
        }
        let (_dir, path) = certificate_file("{\"tile\": ");
        assert!(
            TileCertificate::read(&path, day("2026-12-02"))
                .unwrap_err()
                .to_string()
                .contains("line 1")
        );
        let missing = std::path::Path::new("/nowhere/tile.json");
        assert!(
            TileCertificate::read(missing, day("2026-12-02"))
                .unwrap_err()
                .to_string()
                .contains("cannot read")
        );
        let (_dir, path) = certificate_file("");
        std::fs::write(&path, [0xff, 0xfe, b'{']).unwrap();
        assert!(
            TileCertificate::read(&path, day("2026-12-02"))
                .unwrap_err()
                .to_string()
                .contains("not UTF-8")
        );
    }

    #[test]
    fn a_damaged_file_is_refused_saying_what_is_wrong() {
        let info = firmware::config::InstrumentConfig::REFERENCE.device_info("test");
        let mut c = calibration();
        c.instrument = instrument_name(&info);
        c.taken_unix_s = unix_now_s();
        let path =
            std::env::temp_dir().join(format!("gonio-calibration-{}.json", std::process::id()));
        let damaged = |edit: &dyn Fn(&mut serde_json::Value)| {
            let mut value = serde_json::to_value(&c).unwrap();
            edit(&mut value);
            std::fs::write(&path, serde_json::to_vec(&value).unwrap()).unwrap();
            Calibration::load(&path, Duration::from_secs(3600), &info)
                .map(|_| ())
                .map_err(|e| e.to_string())
        };
        assert_eq!(damaged(&|_| {}), Ok(()));
        type Edit<'a> = &'a dyn Fn(&mut serde_json::Value);
        let cases: [(Edit, &str); 4] = [
            (
                &|v| v["relative_gains"][1] = (-0.1).into(),
                "relative gains",
            ),
            (
                &|v| v["white_relative_uncertainty"] = 2.0.into(),
                "uncertainty 200 %",
            ),
            (&|v| v["lamp_drift_per_hour"] = (-1.0).into(), "lamp drift"),
            (&|v| v["dark"] = serde_json::json!([]), "dark readings"),
        ];
        for (edit, says) in cases {
            let error = damaged(edit).unwrap_err();
            assert!(
                error.contains(&path.display().to_string()) && error.contains(says),
                "{error}"
            );
        }
        let _ = std::fs::remove_file(&path);
    }
}
