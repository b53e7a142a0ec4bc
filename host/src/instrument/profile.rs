//! The instrument profile: what `gonio characterize` measured on one instrument with the
//! lab's standards (`instrument.json`, schema `gonio-instrument/1`, docs/FORMATS.md), and
//! what a session takes from it: the detector's measured angular response in place of the
//! declared top-hat, the arm zero per incidence and its uncertainty.
//!
//! A profile is read whole and checked before anything uses it (every figure finite, the
//! response a usable one, the zero within the arms' reach); a file that is not one is
//! refused with what is wrong and where. Sessions record the profile's SHA-256, serial and
//! date with the figures they used ([`ProfileInUse`]), so `gonio fit DIR` makes the same
//! analysis without the file.
use crate::analysis::model::{DetectorResponse, ResponseError};
use crate::analysis::response_estimate::Measured;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::path::{Path, PathBuf};

/// A profile's schema.
pub const SCHEMA: &str = crate::schema::INSTRUMENT_PROFILE;

/// Age beyond which a profile is taken as no profile unless the lab sets another limit,
/// days: a detector's alignment and a lamp's beam move with handling and ageing; a gloss
/// meter's calibration on its black glass is a daily-to-monthly check, a reflectometer's
/// characterization a yearly one at most.
pub const DEFAULT_MAX_AGE_DAYS: f64 = 90.0;

/// The certified standards used.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Standards {
    /// The black glass (gloss standard).
    pub black_glass: BlackGlass,
    /// The white tile.
    pub white_tile: WhiteTile,
}

/// A black glass gloss standard and its certificate.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BlackGlass {
    /// Its identification (certificate number).
    pub id: String,
    /// Refractive index at the sodium D line (the primary standard's is 1.567).
    pub refractive_index: f64,
    /// Certified gloss units per geometry, (angle in degrees, GU).
    pub certified_gu: Vec<(f64, f64)>,
}

/// A white tile and its certificate.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WhiteTile {
    /// Its identification.
    pub id: String,
    /// Certified radiance factor.
    pub radiance_factor: f64,
}

/// The response as measured, and as the fit uses it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ResponseFigures {
    /// Full width at half maximum, degrees (the incidences' mean and its standard error).
    pub fwhm_deg: Measured,
    /// The width of the top-hat of the same variance, degrees.
    pub equivalent_width_deg: Measured,
    /// What the firmware declares (a top-hat of this full width), degrees.
    pub declared_acceptance_deg: f64,
    /// The fit's histogram: width of each step, degrees.
    pub step_deg: f64,
    /// Offset of the first step's centre from the reading's θr, degrees.
    pub first_offset_deg: f64,
    /// Each step's share of the response (they sum to 1).
    pub shares: Vec<f64>,
    /// Each share's standard uncertainty.
    pub shares_u: Vec<f64>,
}

/// What the sweeps at one incidence gave.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IncidenceFigures {
    /// θi, degrees.
    pub theta_i_deg: f64,
    /// Arm zero: what every firmware θr lacks, degrees (true θr = firmware θr + zero).
    pub arm_zero_deg: Measured,
    /// FWHM of the peak here, degrees.
    pub fwhm_deg: Measured,
    /// The range the peak was read on.
    pub range: u8,
}

/// A gain ratio of two adjacent ranges.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GainRatioFigure {
    /// The more sensitive range r (the ratio is G(r + 1)/G(r)).
    pub range: u8,
    /// The ratio measured.
    pub ratio: Measured,
    /// The firmware's nominal ratio.
    pub nominal: f64,
}

/// Noise of one range.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RangeNoise {
    /// The range.
    pub range: u8,
    /// Dark reading: mean and standard deviation of repeated readings, counts.
    pub dark_counts: Measured,
    /// Relative standard deviation of repeated white readings (where the tile reads in the
    /// range's scale), at the integration time below.
    pub white_relative_sd: Option<f64>,
    /// Integration time of those readings, ms.
    pub integration_ms: u16,
}

/// The lamp's drift over the characterization.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LampFigures {
    /// Drift of the white reading, percent per hour (slope of repeated readings).
    pub drift_pct_per_h: Measured,
    /// Over how long it was measured, s of device time.
    pub over_s: f64,
}

/// An instrument profile (`instrument.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InstrumentProfile {
    /// [`SCHEMA`].
    pub schema: String,
    /// The instrument's serial number (its handshake's).
    pub serial_number: String,
    /// Its firmware version.
    pub firmware_version: String,
    /// The gonio that measured it.
    pub gonio_version: String,
    /// When, RFC 3339 UTC.
    pub measured_at: String,
    /// Device time the characterization took, s.
    pub device_seconds: f64,
    /// The standards.
    pub standards: Standards,
    /// The angular response.
    pub response: ResponseFigures,
    /// Per incidence: arm zero and width.
    pub incidences: Vec<IncidenceFigures>,
    /// Standard uncertainty of the arm zero a session takes from this profile, degrees:
    /// the zeros' own and the homing's repeatability (every session homes again).
    pub arm_zero_u_deg: f64,
    /// The detector arm's backlash: a peak's centroid sweeping up less sweeping down,
    /// degrees.
    pub backlash_deg: Measured,
    /// Standard deviation of the peak's centroid after repeated homing, degrees.
    pub home_repeatability_deg: Measured,
    /// Gain ratios of adjacent ranges.
    pub gain_ratios: Vec<GainRatioFigure>,
    /// Noise per range.
    pub noise: Vec<RangeNoise>,
    /// The lamp.
    pub lamp: LampFigures,
}

/// Why a profile cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum ProfileError {
    /// The file cannot be read.
    #[error("cannot read the instrument profile {path}: {source}")]
    Read {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// It is not a profile of this schema.
    #[error("{path} is not an instrument profile gonio reads: {why}")]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong, where.
        why: String,
    },
    /// A figure is out of its range.
    #[error("{path}: {field} is {value}, {why}")]
    Figure {
        /// The file.
        path: PathBuf,
        /// Which figure.
        field: String,
        /// Its value.
        value: f64,
        /// What it must be.
        why: &'static str,
    },
    /// Its response is not one the fit can use.
    #[error("{path}: the response is not usable: {0}", path = .1.display())]
    Response(#[source] ResponseError, PathBuf),
    /// It was measured on another instrument.
    #[error(
        "{path} is the profile of instrument {profile}, not of the instrument attached ({attached})"
    )]
    OtherInstrument {
        /// The file.
        path: PathBuf,
        /// Its serial.
        profile: String,
        /// The instrument's.
        attached: String,
    },
}

impl InstrumentProfile {
    /// Parse and check a profile's bytes (`path` names it in errors).
    pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<InstrumentProfile, ProfileError> {
        let format = |why: String| ProfileError::Format {
            path: path.to_path_buf(),
            why,
        };
        let value: serde_json::Value =
            serde_json::from_slice(bytes).map_err(|e| format(e.to_string()))?;
        crate::schema::check(&value, &[SCHEMA], None).map_err(|e| format(e.to_string()))?;
        let profile: InstrumentProfile =
            serde_json::from_value(value).map_err(|e| format(e.to_string()))?;
        profile.validate(path)?;
        Ok(profile)
    }

    /// Every figure within its range and the response usable.
    pub fn validate(&self, path: &Path) -> Result<(), ProfileError> {
        let figure = |field: &str, value: f64, ok: bool, why: &'static str| {
            if ok && value.is_finite() {
                Ok(())
            } else {
                Err(ProfileError::Figure {
                    path: path.to_path_buf(),
                    field: field.to_string(),
                    value,
                    why,
                })
            }
        };
        let r = &self.response;
        for (name, m) in [
            ("response.fwhm_deg", r.fwhm_deg),
            ("response.equivalent_width_deg", r.equivalent_width_deg),
        ] {
            figure(
                name,
                m.value,
                m.value > 0.0 && m.value <= 10.0,
                "a width in (0, 10] degrees",
            )?;
            figure(
                &format!("{name}.u"),
                m.u,
                m.u >= 0.0,
                "a standard uncertainty ≥ 0",
            )?;
        }
        if r.shares_u.len() != r.shares.len() {
            return Err(ProfileError::Format {
                path: path.to_path_buf(),
                why: format!(
                    "response.shares has {} values and response.shares_u {}",
                    r.shares.len(),
                    r.shares_u.len()
                ),
            });
        }
        self.response()
            .map_err(|e| ProfileError::Response(e, path.to_path_buf()))?;
        if self.incidences.is_empty() {
            return Err(ProfileError::Format {
                path: path.to_path_buf(),
                why: "no incidence measured (incidences is empty)".into(),
            });
        }
        for (k, inc) in self.incidences.iter().enumerate() {
            figure(
                &format!("incidences[{k}].theta_i_deg"),
                inc.theta_i_deg,
                (0.0..=90.0).contains(&inc.theta_i_deg),
                "an angle in [0, 90] degrees",
            )?;
            figure(
                &format!("incidences[{k}].arm_zero_deg"),
                inc.arm_zero_deg.value,
                inc.arm_zero_deg.value.abs() <= 5.0,
                "an arm zero within ±5 degrees",
            )?;
            figure(
                &format!("incidences[{k}].arm_zero_deg.u"),
                inc.arm_zero_deg.u,
                inc.arm_zero_deg.u >= 0.0,
                "a standard uncertainty ≥ 0",
            )?;
        }
        figure(
            "arm_zero_u_deg",
            self.arm_zero_u_deg,
            (0.0..=5.0).contains(&self.arm_zero_u_deg),
            "a standard uncertainty in [0, 5] degrees",
        )?;
        figure(
            "standards.black_glass.refractive_index",
            self.standards.black_glass.refractive_index,
            (1.0..=3.0).contains(&self.standards.black_glass.refractive_index),
            "an index in [1, 3]",
        )?;
        chrono::DateTime::parse_from_rfc3339(&self.measured_at).map_err(|e| {
            ProfileError::Format {
                path: path.to_path_buf(),
                why: format!(
                    "measured_at '{}' is not an RFC 3339 time: {e}",
                    self.measured_at
                ),
            }
        })?;
        Ok(())
    }

    /// The measured response as the fit uses it.
    pub fn response(&self) -> Result<DetectorResponse, ResponseError> {
        DetectorResponse::from_steps(
            self.response.step_deg,
            self.response.first_offset_deg,
            &self.response.shares,
        )
    }

    /// Its age at `now_unix_s`, days (negative for a date in the future).
    pub fn age_days(&self, now_unix_s: u64) -> f64 {
        chrono::DateTime::parse_from_rfc3339(&self.measured_at).map_or(f64::INFINITY, |t| {
            (now_unix_s as f64 - t.timestamp() as f64) / 86_400.0
        })
    }

    /// What a session takes from it, with the file's hash and its age now.
    pub fn in_use(&self, sha256: String, now_unix_s: u64) -> ProfileInUse {
        let mut zeros: Vec<(f64, f64)> = self
            .incidences
            .iter()
            .map(|i| (i.theta_i_deg, i.arm_zero_deg.value))
            .collect();
        zeros.sort_by(|a, b| a.0.total_cmp(&b.0));
        ProfileInUse {
            sha256,
            serial_number: self.serial_number.clone(),
            measured_at: self.measured_at.clone(),
            age_days: self.age_days(now_unix_s),
            step_deg: self.response.step_deg,
            first_offset_deg: self.response.first_offset_deg,
            shares: self.response.shares.clone(),
            fwhm_deg: self.response.fwhm_deg.value,
            arm_zero_deg: zeros,
            arm_zero_u_deg: self.arm_zero_u_deg,
        }
    }
}

/// What a session used of a profile, recorded with its analysis so that a re-analysis
/// makes the same one without the file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ProfileInUse {
    /// SHA-256 of the profile file, hex.
    pub sha256: String,
    /// The instrument it was measured on.
    pub serial_number: String,
    /// When it was measured.
    pub measured_at: String,
    /// Its age when the session used it, days.
    pub age_days: f64,
    /// The response's step, degrees.
    pub step_deg: f64,
    /// Its first step's offset, degrees.
    pub first_offset_deg: f64,
    /// Its steps' shares.
    pub shares: Vec<f64>,
    /// Its FWHM, degrees (for the record).
    pub fwhm_deg: f64,
    /// (θi, arm zero) per incidence, degrees, by θi.
    pub arm_zero_deg: Vec<(f64, f64)>,
    /// The arm zero's standard uncertainty, degrees.
    pub arm_zero_u_deg: f64,
}

impl ProfileInUse {
    /// The response.
    pub fn response(&self) -> Result<DetectorResponse, ResponseError> {
        DetectorResponse::from_steps(self.step_deg, self.first_offset_deg, &self.shares)
    }

    /// A firmware θr with the zero added: the true θr, held within [0°, 90°) where the
    /// fit takes readings (a reading at the firmware's 0° is then at 0°, not a hair past
    /// the normal: the model there is flat in θr, so the hair does not matter).
    pub fn corrected_theta_r(&self, theta_i_deg: f64, theta_r_deg: f64) -> f64 {
        (theta_r_deg + self.arm_zero_at(theta_i_deg)).clamp(0.0, 89.999)
    }

    /// The arm zero at `theta_i_deg`: linear between the incidences measured, the nearest
    /// one's beyond them.
    pub fn arm_zero_at(&self, theta_i_deg: f64) -> f64 {
        let z = &self.arm_zero_deg;
        match z.len() {
            0 => 0.0,
            1 => z[0].1,
            _ => {
                if theta_i_deg <= z[0].0 {
                    return z[0].1;
                }
                for w in z.windows(2) {
                    if theta_i_deg <= w[1].0 {
                        let t = (theta_i_deg - w[0].0) / (w[1].0 - w[0].0);
                        return w[0].1 + t * (w[1].1 - w[0].1);
                    }
                }
                z[z.len() - 1].1
            }
        }
    }
}

/// SHA-256 of `bytes`, lower-case hex.
pub fn sha256_hex(bytes: &[u8]) -> String {
    Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// Read and check the profile at `path`: the profile and its file's SHA-256.
pub fn read(path: &Path) -> Result<(InstrumentProfile, String), ProfileError> {
    let bytes = std::fs::read(path).map_err(|source| ProfileError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    let profile = InstrumentProfile::from_bytes(&bytes, path)?;
    Ok((profile, sha256_hex(&bytes)))
}

/// Where the profile of instrument `serial` is kept when none is named:
/// `$XDG_DATA_HOME/gonio/instruments/SERIAL.json`, else
/// `$HOME/.local/share/gonio/instruments/SERIAL.json` (as the library). `None` without
/// either variable, or for a serial that is not a plain file name.
pub fn default_path(serial: &str) -> Option<PathBuf> {
    let plain = !serial.is_empty()
        && serial
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_' || c == '.')
        && !serial.starts_with('.');
    if !plain {
        return None;
    }
    Some(
        super::data_dir()?
            .join("instruments")
            .join(format!("{serial}.json")),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn profile_in_use(zeros: Vec<(f64, f64)>) -> ProfileInUse {
        ProfileInUse {
            sha256: String::new(),
            serial_number: "X".into(),
            measured_at: "2026-12-03T00:00:00Z".into(),
            age_days: 0.0,
            step_deg: 0.5,
            first_offset_deg: -0.5,
            shares: vec![0.25, 0.5, 0.25],
            fwhm_deg: 1.0,
            arm_zero_deg: zeros,
            arm_zero_u_deg: 0.01,
        }
    }

    #[test]
    fn the_arm_zero_is_interpolated_between_incidences_and_held_beyond() {
        let p = profile_in_use(vec![(20.0, 0.1), (60.0, 0.3)]);
        assert_eq!(p.arm_zero_at(10.0), 0.1);
        assert!((p.arm_zero_at(40.0) - 0.2).abs() < 1e-12);
        assert_eq!(p.arm_zero_at(75.0), 0.3);
        assert_eq!(profile_in_use(vec![]).arm_zero_at(30.0), 0.0);
        assert!(p.response().unwrap().mean_deg().abs() < 1e-12);
    }

    #[test]
    fn serials_that_are_not_file_names_have_no_default_place() {
        for bad in ["", "../x", "a/b", ".hidden", "a b"] {
            assert_eq!(default_path(bad), None, "{bad}");
        }
        assert_eq!(sha256_hex(b"").len(), 64);
    }
}
