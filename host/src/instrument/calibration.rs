//! Dark and white calibration, and the conversion of detector readings to radiance
//! factors with their uncertainty (INSTRUMENT.md, "Calibration").
//!
//! R = (S − S_dark) / (S_white − S_dark) · R_white at the same θi. A sample reading and
//! the white reading at its θi may be on different ranges (a glossy peak needs the least
//! sensitive one); the counts are then divided by the ranges' relative gains announced in
//! the handshake.

use protocol::{DeviceInfo, Reading};
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

/// The white tile's certified radiance factor, unless a calibration says otherwise.
pub const DEFAULT_WHITE_RADIANCE_FACTOR: f64 = 0.99;

/// One white-tile reading, at θr = 0 (the tile is Lambertian: one θr serves all).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct WhitePoint {
    /// Incidence angle, degrees.
    pub theta_i_deg: f64,
    /// The reading.
    pub reading: Reading,
}

/// A calibration: dark per range, white per incidence angle.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Calibration {
    /// When it was taken, seconds since the Unix epoch.
    pub taken_unix_s: u64,
    /// The instrument it was taken on (board and firmware).
    pub instrument: String,
    /// Certified radiance factor of the white tile used.
    pub white_radiance_factor: f64,
    /// Relative gain of each detector range, most sensitive first.
    pub relative_gains: Vec<f64>,
    /// Dark reading per range (lamp off), most sensitive first.
    pub dark: Vec<Reading>,
    /// White readings, one per incidence angle.
    pub white: Vec<WhitePoint>,
}

/// Why a reading cannot be converted, or a calibration not used.
#[derive(Debug, thiserror::Error)]
pub enum CalibrationError {
    /// No white reading at this incidence angle.
    #[error("no white reading at θi = {0}° in the calibration")]
    NoWhite(f64),
    /// No dark reading or gain for a range.
    #[error("no dark reading or gain for detector range {0}")]
    NoRange(u8),
    /// The reading saturated the least sensitive range: its value is only a lower bound.
    #[error("the reading saturated the detector's least sensitive range")]
    Saturated,
    /// The white reading is not above dark.
    #[error("the white reading at θi = {0}° is not above dark: was the lamp on and the tile in place?")]
    WhiteNotAboveDark(f64),
    /// Older than allowed.
    #[error("calibration {path} is {age_h:.1} h old; the limit is {max_h:.1} h: calibrate again (omit --calibration)")]
    Stale {
        /// The file.
        path: String,
        /// Its age, hours.
        age_h: f64,
        /// The limit, hours.
        max_h: f64,
    },
    /// Taken on another instrument.
    #[error("calibration {path} was taken on '{taken_on}', not on this instrument ('{this}')")]
    OtherInstrument {
        /// The file.
        path: String,
        /// Where it was taken.
        taken_on: String,
        /// This instrument.
        this: String,
    },
    /// A maximum age that is no number of hours (`--max-calibration-age-h`).
    #[error("--max-calibration-age-h must be a number of hours above 0 and at most {MAX_CALIBRATION_AGE_H} (a year), not {0:?}")]
    BadMaxAge(f64),
    /// The file could not be read.
    #[error("cannot read calibration {path}: {why}")]
    Unreadable {
        /// The file.
        path: String,
        /// Why.
        why: String,
    },
}

/// The longest `--max-calibration-age-h` accepted: a year. A lamp and a white tile are not
/// stable for longer, and it keeps the age a [`Duration`] can hold.
pub const MAX_CALIBRATION_AGE_H: f64 = 8760.0;

/// The oldest calibration accepted, from `--max-calibration-age-h`: a finite number of
/// hours in (0, [`MAX_CALIBRATION_AGE_H`]], else [`CalibrationError::BadMaxAge`] naming it.
pub fn max_age_from_hours(hours: f64) -> Result<Duration, CalibrationError> {
    if !(hours > 0.0 && hours <= MAX_CALIBRATION_AGE_H) {
        return Err(CalibrationError::BadMaxAge(hours));
    }
    Duration::try_from_secs_f64(hours * 3600.0).map_err(|_| CalibrationError::BadMaxAge(hours))
}

/// The instrument's identity as a calibration records it.
pub fn instrument_name(info: &DeviceInfo) -> String {
    format!("{} (firmware {})", info.board, info.firmware_version)
}

/// Seconds since the Unix epoch now.
pub fn unix_now_s() -> u64 {
    SystemTime::now().duration_since(UNIX_EPOCH).map_or(0, |d| d.as_secs())
}

/// A reading's mean above dark, in counts of the most sensitive range, and its standard
/// uncertainty (the standard errors of both means).
fn net_counts(reading: &Reading, dark: &[Reading], gains: &[f64]) -> Result<(f64, f64), CalibrationError> {
    let range = usize::from(reading.range);
    let (Some(d), Some(&gain)) = (dark.get(range), gains.get(range)) else {
        return Err(CalibrationError::NoRange(reading.range));
    };
    let sem = |r: &Reading| f64::from(r.std_counts) / f64::from(r.samples.max(1)).sqrt();
    let net = (f64::from(reading.mean_counts) - f64::from(d.mean_counts)) / gain;
    let u = (sem(reading).powi(2) + sem(d).powi(2)).sqrt() / gain;
    Ok((net, u))
}

impl Calibration {
    /// Radiance factor and its standard uncertainty of a sample reading at `theta_i_deg`.
    pub fn radiance_factor(&self, theta_i_deg: f64, reading: &Reading) -> Result<(f64, f64), CalibrationError> {
        if reading.saturated {
            return Err(CalibrationError::Saturated);
        }
        let white = self
            .white
            .iter()
            .find(|w| (w.theta_i_deg - theta_i_deg).abs() < 1e-6)
            .ok_or(CalibrationError::NoWhite(theta_i_deg))?;
        let (s, us) = net_counts(reading, &self.dark, &self.relative_gains)?;
        let (w, uw) = net_counts(&white.reading, &self.dark, &self.relative_gains)?;
        if w <= 0.0 || white.reading.saturated {
            return Err(CalibrationError::WhiteNotAboveDark(theta_i_deg));
        }
        let r = s / w * self.white_radiance_factor;
        let u = self.white_radiance_factor * ((us / w).powi(2) + (s * uw / (w * w)).powi(2)).sqrt();
        Ok((r, u))
    }

    /// Age at `now_unix_s`.
    pub fn age(&self, now_unix_s: u64) -> Duration {
        Duration::from_secs(now_unix_s.saturating_sub(self.taken_unix_s))
    }

    /// Read a calibration saved by an earlier session (its `calibration.json`, or the
    /// `session.json` that holds one), refusing it when older than `max_age` or taken on
    /// another instrument.
    pub fn load(path: &Path, max_age: Duration, info: &DeviceInfo) -> Result<Calibration, CalibrationError> {
        let unreadable = |why: String| CalibrationError::Unreadable { path: path.display().to_string(), why };
        let text = std::fs::read_to_string(path).map_err(|e| unreadable(e.to_string()))?;
        let value: serde_json::Value = serde_json::from_str(&text).map_err(|e| unreadable(e.to_string()))?;
        let calibration_value = value.get("calibration").cloned().unwrap_or(value);
        let calibration: Calibration = serde_json::from_value(calibration_value).map_err(|e| unreadable(e.to_string()))?;
        calibration.check(&path.display().to_string(), max_age, info)?;
        Ok(calibration)
    }

    /// Refuse this calibration (from `path`, for messages) when older than `max_age` or
    /// taken on another instrument than `info`'s.
    pub fn check(&self, path: &str, max_age: Duration, info: &DeviceInfo) -> Result<(), CalibrationError> {
        let age = self.age(unix_now_s());
        if age > max_age {
            return Err(CalibrationError::Stale { path: path.to_string(), age_h: age.as_secs_f64() / 3600.0, max_h: max_age.as_secs_f64() / 3600.0 });
        }
        let this = instrument_name(info);
        if self.instrument != this {
            return Err(CalibrationError::OtherInstrument { path: path.to_string(), taken_on: self.instrument.clone(), this });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reading(mean_counts: f32, range: u8) -> Reading {
        Reading { mean_counts, std_counts: 10.0, samples: 100, range, integration_ms: 100, saturated: false }
    }

    fn calibration() -> Calibration {
        Calibration {
            taken_unix_s: 1_000,
            instrument: "test".into(),
            white_radiance_factor: 0.99,
            relative_gains: vec![1.0, 0.1, 0.01],
            dark: vec![reading(200.0, 0), reading(200.0, 1), reading(200.0, 2)],
            white: vec![WhitePoint { theta_i_deg: 20.0, reading: reading(26_200.0, 0) }],
        }
    }

    #[test]
    fn converts_across_ranges_with_uncertainty() {
        let c = calibration();
        // Half the white signal on range 0: R = 0.495.
        let (r, u) = c.radiance_factor(20.0, &reading(13_200.0, 0)).unwrap();
        assert!((r - 0.495).abs() < 1e-12);
        assert!(u > 0.0 && u < 1e-3);
        // Twenty times the white signal, read on range 2 (gain 0.01): R = 19.8.
        let (r, _) = c.radiance_factor(20.0, &reading(200.0 + 5_200.0, 2)).unwrap();
        assert!((r - 19.8).abs() < 1e-9, "{r}");
    }

    #[test]
    fn a_maximum_age_is_a_number_of_hours_a_duration_holds() {
        assert_eq!(max_age_from_hours(8.0).unwrap(), Duration::from_secs(8 * 3600));
        assert_eq!(max_age_from_hours(MAX_CALIBRATION_AGE_H).unwrap(), Duration::from_secs(8760 * 3600));
        for bad in [f64::INFINITY, f64::NAN, -1.0, 0.0, 1e300, MAX_CALIBRATION_AGE_H + 1.0, f64::NEG_INFINITY] {
            let error = max_age_from_hours(bad).unwrap_err().to_string();
            assert!(error.contains("--max-calibration-age-h") && error.contains(&format!("{bad:?}")), "{error}");
        }
    }

    #[test]
    fn refuses_what_it_cannot_convert() {
        let c = calibration();
        assert!(matches!(c.radiance_factor(30.0, &reading(1.0, 0)), Err(CalibrationError::NoWhite(_))));
        assert!(matches!(c.radiance_factor(20.0, &reading(1.0, 3)), Err(CalibrationError::NoRange(3))));
        let saturated = Reading { saturated: true, ..reading(65_535.0, 2) };
        assert!(matches!(c.radiance_factor(20.0, &saturated), Err(CalibrationError::Saturated)));
    }
}
