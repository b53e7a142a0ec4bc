//! The calibration's data and maths, pure (no I/O): the white tile and its certificate,
//! the dark and white readings, the range gains, and the conversion of detector readings
//! to radiance factors (the reference instrument's calibration).
//!
//! R = (S − S_dark) / (S_white − S_dark) · R_tile at the same θi. A sample reading and the
//! white reading at its θi may be on different ranges (a glossy peak needs the least
//! sensitive one); the counts are then divided by the ranges' relative gains: the ratios
//! of adjacent ranges calibrated in the session where they were ([`GainRatio`], made by
//! `session::gains`), else the nominal ones the handshake announces.
//!
//! The standard uncertainty a conversion gives is the reading's *own* noise only (the
//! standard error of its mean). Everything a reading shares with others — the white
//! reading at its θi, the dark of a range, the tile's certificate, a range gain, the lamp's
//! drift since the white reading — is an error common to many readings, and is carried as
//! such by [`crate::analysis::budget`], which builds those terms from this calibration.
//! Reading a certificate or a calibration file, and the clock, are
//! `instrument::calibration`'s.

use protocol::Reading;
use serde::{Deserialize, Serialize};
use std::time::Duration;

/// The white tile's certified radiance factor unless the user gives the certificate's
/// (`--tile-radiance-factor`): the reference instrument's tile.
pub const DEFAULT_WHITE_RADIANCE_FACTOR: f64 = 0.99;

/// Relative standard uncertainty (k = 1) of the tile's certified radiance factor unless the
/// user gives the certificate's (`--tile-uncertainty-pct`). An assumption: working-standard
/// white tiles (sintered PTFE, ceramic) are certified for 0°/45° to about ±1 % at k = 2.
/// A certificate's expanded uncertainty (k = 2) is twice the value to give here.
pub const DEFAULT_TILE_RELATIVE_UNCERTAINTY: f64 = 0.005;

/// Relative standard uncertainty of a nominal (uncalibrated) gain ratio of adjacent ranges.
/// An instrument assumption: the firmware's configuration (`firmware::config`, three
/// transimpedance ranges a decade apart, announced as exactly 1, 0.1, 0.01) says nothing of
/// their tolerance; 1 % feedback resistors and the amplifier's finite open-loop gain make a
/// ratio good to about 1 %. A session calibrates the ratios its readings use
/// (`session::gains`); this applies only where it could not.
pub(crate) const NOMINAL_GAIN_RATIO_RELATIVE_UNCERTAINTY: f64 = 0.01;

/// Lamp output drift, standard uncertainty of its rate, per hour (fraction). The reference instrument:
/// "lamp drift 0.2 % per hour" for the reference instrument; its sign is not known, so the
/// rate is taken as 0 ± 0.2 %/h.
pub(crate) const DEFAULT_LAMP_DRIFT_PER_HOUR: f64 = 0.002;

/// The white tile a calibration is taken with: its certified radiance factor and that
/// value's uncertainty, and the certificate they come from when one was given.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Tile {
    /// Certified radiance factor.
    pub radiance_factor: f64,
    /// Relative standard uncertainty (k = 1) of it.
    pub relative_uncertainty: f64,
    /// The certificate (`--tile-certificate`); `None` when the values were given on the
    /// command line or are the defaults.
    pub certificate: Option<TileCertificate>,
}

impl Default for Tile {
    fn default() -> Self {
        Tile {
            radiance_factor: DEFAULT_WHITE_RADIANCE_FACTOR,
            relative_uncertainty: DEFAULT_TILE_RELATIVE_UNCERTAINTY,
            certificate: None,
        }
    }
}

/// A white tile's calibration certificate as the user transcribes it into a small JSON
/// file (`gonio measure --tile-certificate FILE`; its fields in docs/FORMATS.md), and as
/// every calibration taken with it records it (with the file's SHA-256).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TileCertificate {
    /// [`crate::schema::TILE_CERTIFICATE`]; optional in the file a person writes.
    #[serde(default)]
    pub schema: Option<String>,
    /// The tile: maker, model and serial number.
    pub tile: String,
    /// The certificate's number.
    pub certificate: String,
    /// The laboratory that issued it.
    #[serde(default)]
    pub issued_by: Option<String>,
    /// Date of issue, YYYY-MM-DD.
    pub issued: String,
    /// Date until which it is valid, YYYY-MM-DD, when it says.
    #[serde(default)]
    pub valid_until: Option<String>,
    /// The certified radiance factor for the instrument's geometry (0° incidence onto the
    /// tile as the detector at θr = 0 sees it; V(λ)-weighted, as the detector is).
    pub radiance_factor: f64,
    /// The certificate's expanded uncertainty of it, absolute (the same unit).
    pub expanded_uncertainty: f64,
    /// Its coverage factor k (2 when the certificate gives none: about 95 %).
    #[serde(default = "default_coverage_factor")]
    pub coverage_factor: f64,
    /// SHA-256 of the certificate file as read (filled in by gonio; not in the user's file).
    #[serde(default)]
    pub file_sha256: Option<String>,
}

fn default_coverage_factor() -> f64 {
    2.0
}

/// The earliest date of issue a tile certificate may have: this instrument and its
/// protocol are of the 2020s, and a white tile is re-certified every few years, so an
/// older date is a typing error (issue 30: one of 1900 was accepted).
pub const EARLIEST_ISSUE: chrono::NaiveDate = match chrono::NaiveDate::from_ymd_opt(2000, 1, 1) {
    Some(date) => date,
    None => panic!("a valid date"),
};

/// What is wrong with a tile certificate's values (the caller names the file).
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub(crate) enum CertificateError {
    /// A name (tile, certificate, issuer) that is empty, too long or has control characters.
    #[error(
        "'{key}' must be a name of 1 to 200 characters without control characters, not {text:?}"
    )]
    BadName {
        /// The key in the file.
        key: &'static str,
        /// Its value.
        text: String,
    },
    /// A date that is not YYYY-MM-DD.
    #[error("'{key}' must be a date YYYY-MM-DD, not {text:?}")]
    BadDate {
        /// The key in the file.
        key: &'static str,
        /// Its value.
        text: String,
    },
    /// Issued after the session's date.
    #[error("issued {issued}, after today ({today}): check the date")]
    IssuedAfterToday {
        /// Date of issue.
        issued: chrono::NaiveDate,
        /// The session's date.
        today: chrono::NaiveDate,
    },
    /// Issued before any tile could have been certified for this instrument: a typing
    /// error (a year like 1900 or 0026) that would pass a certificate off as valid.
    #[error(
        "issued {issued}, before {EARLIEST_ISSUE} (no certificate of a tile for this kind of instrument is that old): check the date"
    )]
    IssuedTooEarly {
        /// Date of issue.
        issued: chrono::NaiveDate,
    },
    /// Valid until a date before its issue.
    #[error("valid until {until}, before it was issued ({issued}): check the dates")]
    ValidBeforeIssued {
        /// Date of issue.
        issued: chrono::NaiveDate,
        /// End of validity.
        until: chrono::NaiveDate,
    },
    /// Valid until a date before the session's.
    #[error(
        "expired on {0}: have the tile certified again, or give its values with --tile-radiance-factor and --tile-uncertainty-pct (then no certificate is recorded)"
    )]
    Expired(chrono::NaiveDate),
    /// A coverage factor outside [1, 4].
    #[error("'coverage_factor' must be between 1 and 4, not {0}")]
    BadCoverageFactor(f64),
    /// An expanded uncertainty that is negative or not a number.
    #[error(
        "'expanded_uncertainty' must be a number at least 0 (absolute, in radiance factor), not {0}"
    )]
    BadExpandedUncertainty(f64),
}

impl TileCertificate {
    /// Check the values a person transcribed; `today` is the local date of the session: a
    /// certificate issued after it, or expired before it, is refused.
    pub(crate) fn validate(&self, today: chrono::NaiveDate) -> Result<(), CertificateError> {
        for (key, text) in [
            ("tile", Some(&self.tile)),
            ("certificate", Some(&self.certificate)),
            ("issued_by", self.issued_by.as_ref()),
        ] {
            if let Some(text) = text
                && (text.trim().is_empty()
                    || text.chars().any(char::is_control)
                    || text.chars().count() > 200)
            {
                return Err(CertificateError::BadName {
                    key,
                    text: text.clone(),
                });
            }
        }
        let date = |key: &'static str, text: &str| {
            chrono::NaiveDate::parse_from_str(text, "%Y-%m-%d").map_err(|_| {
                CertificateError::BadDate {
                    key,
                    text: text.to_string(),
                }
            })
        };
        let issued = date("issued", &self.issued)?;
        if issued > today {
            return Err(CertificateError::IssuedAfterToday { issued, today });
        }
        if issued < EARLIEST_ISSUE {
            return Err(CertificateError::IssuedTooEarly { issued });
        }
        if let Some(until) = &self.valid_until {
            let until = date("valid_until", until)?;
            if until < issued {
                return Err(CertificateError::ValidBeforeIssued { issued, until });
            }
            if until < today {
                return Err(CertificateError::Expired(until));
            }
        }
        if !(self.coverage_factor.is_finite() && (1.0..=4.0).contains(&self.coverage_factor)) {
            return Err(CertificateError::BadCoverageFactor(self.coverage_factor));
        }
        if !(self.expanded_uncertainty.is_finite() && self.expanded_uncertainty >= 0.0) {
            return Err(CertificateError::BadExpandedUncertainty(
                self.expanded_uncertainty,
            ));
        }
        Ok(())
    }

    /// The tile it certifies.
    pub fn tile(self) -> Result<Tile, CalibrationError> {
        let tile = Tile {
            radiance_factor: self.radiance_factor,
            relative_uncertainty: self.expanded_uncertainty
                / self.coverage_factor
                / self.radiance_factor,
            certificate: None,
        };
        tile.validate()?;
        Ok(Tile {
            certificate: Some(self),
            ..tile
        })
    }
}

impl Tile {
    /// A certificate from the command line's values (the uncertainty in percent, k = 1).
    pub fn new(radiance_factor: f64, uncertainty_pct: f64) -> Result<Tile, CalibrationError> {
        let tile = Tile {
            radiance_factor,
            relative_uncertainty: uncertainty_pct / 100.0,
            certificate: None,
        };
        tile.validate()?;
        Ok(tile)
    }

    fn validate(&self) -> Result<(), CalibrationError> {
        // A white reference reflects at most a little more than a perfect diffuser.
        if !(self.radiance_factor.is_finite()
            && self.radiance_factor > 0.0
            && self.radiance_factor <= 1.2)
        {
            return Err(CalibrationError::BadTile(format!(
                "radiance factor {} is not in (0, 1.2]",
                self.radiance_factor
            )));
        }
        if !(self.relative_uncertainty.is_finite()
            && (0.0..0.5).contains(&self.relative_uncertainty))
        {
            return Err(CalibrationError::BadTile(format!(
                "uncertainty {} % is not in [0, 50) %",
                100.0 * self.relative_uncertainty
            )));
        }
        Ok(())
    }
}

fn default_tile_relative_uncertainty() -> f64 {
    DEFAULT_TILE_RELATIVE_UNCERTAINTY
}

fn default_nominal_gain_ratio_relative_uncertainty() -> f64 {
    NOMINAL_GAIN_RATIO_RELATIVE_UNCERTAINTY
}

fn default_lamp_drift_per_hour() -> f64 {
    DEFAULT_LAMP_DRIFT_PER_HOUR
}

/// One white-tile reading, at θr = 0 (the tile is Lambertian: one θr serves all).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct WhitePoint {
    /// Incidence angle, degrees.
    pub theta_i_deg: f64,
    /// The reading.
    pub reading: Reading,
}

/// The gain ratio of two adjacent ranges, G(r + 1) / G(r), calibrated by reading one scene
/// at one position on both ranges (`session::gains`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GainRatio {
    /// The more sensitive range r of the pair (r, r + 1).
    pub lower_range: u8,
    /// G(r + 1) / G(r): the net counts on r + 1 over the net counts on r.
    pub ratio: f64,
    /// Its relative standard uncertainty from the two readings' own noise (and the lamp's
    /// drift between them). The darks' part is in the dark terms of the budget, which
    /// follow a dark error through this ratio into every reading.
    pub relative_uncertainty: f64,
    /// Where the scene was read: incidence, degrees.
    pub theta_i_deg: f64,
    /// Where the scene was read: detection, degrees.
    pub theta_r_deg: f64,
    /// What was read ("sample" or "white tile").
    pub scene: String,
    /// The readings on range r (pooled when several were taken).
    pub on_lower: Reading,
    /// The readings on range r + 1 (pooled).
    pub on_upper: Reading,
    /// Device time the calibration of this ratio took (search, moves and readings), seconds.
    pub device_seconds: f64,
}

/// A calibration: dark per range, white per incidence angle, the tile, the range gains.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Calibration {
    /// When it was taken, seconds since the Unix epoch.
    pub taken_unix_s: u64,
    /// The instrument it was taken on (board and firmware).
    pub instrument: String,
    /// Certified radiance factor of the white tile used.
    pub white_radiance_factor: f64,
    /// Relative standard uncertainty (k = 1) of the tile's certified radiance factor
    /// (older calibrations without it get [`DEFAULT_TILE_RELATIVE_UNCERTAINTY`]).
    #[serde(default = "default_tile_relative_uncertainty")]
    pub white_relative_uncertainty: f64,
    /// The tile's certificate, when one was given (`--tile-certificate`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub white_certificate: Option<TileCertificate>,
    /// Nominal relative gain of each detector range (the handshake's), most sensitive first.
    pub relative_gains: Vec<f64>,
    /// Relative standard uncertainty assumed for a nominal ratio of adjacent ranges.
    #[serde(default = "default_nominal_gain_ratio_relative_uncertainty")]
    pub(crate) nominal_gain_ratio_relative_uncertainty: f64,
    /// Calibrated ratios of adjacent ranges (only those the readings needed).
    #[serde(default)]
    pub gain_ratios: Vec<GainRatio>,
    /// Standard uncertainty of the lamp's drift rate, per hour (fraction).
    #[serde(default = "default_lamp_drift_per_hour")]
    pub(crate) lamp_drift_per_hour: f64,
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
    #[error(
        "the white reading at θi = {0}° is not above dark: was the lamp on and the tile in place?"
    )]
    WhiteNotAboveDark(f64),
    /// Older than allowed.
    #[error(
        "calibration {path} is {age_h:.1} h old; the limit is {max_h:.1} h: calibrate again (omit --calibration)"
    )]
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
    #[error(
        "--max-calibration-age-h must be a number of hours above 0 and at most {MAX_CALIBRATION_AGE_H} (a year), not {0:?}"
    )]
    BadMaxAge(f64),
    /// A tile certificate that cannot be right.
    #[error("bad white tile certificate: {0}")]
    BadTile(String),
    /// A calibration whose values cannot be right (a hand-edited or damaged file).
    #[error("calibration is not usable: {0}")]
    Invalid(String),
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
pub(crate) const MAX_CALIBRATION_AGE_H: f64 = 8760.0;

/// The oldest calibration accepted, from `--max-calibration-age-h`: a finite number of
/// hours in (0, [`MAX_CALIBRATION_AGE_H`]], else [`CalibrationError::BadMaxAge`] naming it.
pub(crate) fn max_age_from_hours(hours: f64) -> Result<Duration, CalibrationError> {
    if !(hours > 0.0 && hours <= MAX_CALIBRATION_AGE_H) {
        return Err(CalibrationError::BadMaxAge(hours));
    }
    Duration::try_from_secs_f64(hours * 3600.0).map_err(|_| CalibrationError::BadMaxAge(hours))
}

/// The least standard uncertainty of a reading's mean, counts: the ADC's resolution of
/// one count as a rectangular distribution (GUM 4.3.7: 1/√12). Noise averages the rounding
/// down over many samples; without noise (a quiet detector, the simulator's
/// `--noise-scale 0`) every sample rounds the same way and the mean is known to no better.
/// Without the floor such a reading had an uncertainty of 0 and no fit could weigh it.
pub(crate) const RESOLUTION_STD_COUNTS: f64 = 0.288_675_134_594_812_9;

/// Standard error of a reading's mean, counts: its samples' standard deviation over √n, at
/// least [`RESOLUTION_STD_COUNTS`].
pub(crate) fn standard_error_counts(reading: &Reading) -> f64 {
    let noise = f64::from(reading.std_counts) / f64::from(reading.samples.max(1)).sqrt();
    // (NaN stays NaN: the conversion's checks report it.)
    if noise.is_nan() {
        noise
    } else {
        noise.max(RESOLUTION_STD_COUNTS)
    }
}

/// Pool readings of one scene on one range into one, as if it had been one long reading:
/// means weighted by the inverse of their squared standard errors.
pub fn pool(readings: &[Reading]) -> Option<Reading> {
    let first = *readings.first()?;
    let weight = |r: &Reading| 1.0 / standard_error_counts(r).powi(2).max(1e-12);
    let total_weight: f64 = readings.iter().map(weight).sum();
    let mean = readings
        .iter()
        .map(|r| weight(r) * f64::from(r.mean_counts))
        .sum::<f64>()
        / total_weight;
    let samples: u32 = readings
        .iter()
        .map(|r| r.samples)
        .fold(0u32, u32::saturating_add);
    let integration_ms = readings
        .iter()
        .map(|r| u32::from(r.integration_ms))
        .sum::<u32>()
        .min(u32::from(u16::MAX)) as u16;
    let standard_error = total_weight.recip().sqrt();
    Some(Reading {
        mean_counts: mean as f32,
        std_counts: (standard_error * f64::from(samples.max(1)).sqrt()) as f32,
        samples,
        range: first.range,
        integration_ms,
        saturated: readings.iter().any(|r| r.saturated),
    })
}

/// How a reading converts: the parts the uncertainty budget differentiates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Conversion {
    /// The radiance factor.
    pub radiance_factor: f64,
    /// Its standard uncertainty from the reading's own noise only.
    pub(crate) own_std: f64,
    /// The reading's counts above its range's dark (on its own range).
    pub net_counts: f64,
    /// Radiance factor per count above the dark on the reading's range (T/(G·w)): what a
    /// count of dark error is worth, whatever the reading, 0 counts included.
    pub(crate) per_count: f64,
    /// The white reading's counts above its range's dark (on its own range).
    pub(crate) white_net_counts: f64,
    /// Range of the reading.
    pub range: u8,
    /// Range of the white reading at its θi.
    pub(crate) white_range: u8,
    /// Index of the white reading in [`Calibration::white`].
    pub(crate) white_index: usize,
}

impl Calibration {
    /// A calibration taken at `taken_unix_s` from its readings, with the tile's
    /// certificate and the nominal gains of the handshake; no gain ratio calibrated yet.
    pub(crate) fn taken_at(
        taken_unix_s: u64,
        instrument: String,
        tile: Tile,
        relative_gains: Vec<f64>,
        dark: Vec<Reading>,
        white: Vec<WhitePoint>,
    ) -> Calibration {
        Calibration {
            taken_unix_s,
            instrument,
            white_radiance_factor: tile.radiance_factor,
            white_relative_uncertainty: tile.relative_uncertainty,
            white_certificate: tile.certificate,
            relative_gains,
            nominal_gain_ratio_relative_uncertainty: NOMINAL_GAIN_RATIO_RELATIVE_UNCERTAINTY,
            gain_ratios: Vec::new(),
            lamp_drift_per_hour: DEFAULT_LAMP_DRIFT_PER_HOUR,
            dark,
            white,
        }
    }

    /// The tile's certificate this calibration used.
    pub fn tile(&self) -> Tile {
        Tile {
            radiance_factor: self.white_radiance_factor,
            relative_uncertainty: self.white_relative_uncertainty,
            certificate: self.white_certificate.clone(),
        }
    }

    /// The white reading at `theta_i_deg` and its index.
    pub(crate) fn white_at(&self, theta_i_deg: f64) -> Option<(usize, &WhitePoint)> {
        self.white
            .iter()
            .enumerate()
            .find(|(_, w)| (w.theta_i_deg - theta_i_deg).abs() < 1e-6)
    }

    /// The calibrated ratio G(r + 1) / G(r), if there is one.
    pub(crate) fn calibrated_ratio(&self, lower_range: u8) -> Option<&GainRatio> {
        self.gain_ratios
            .iter()
            .rev()
            .find(|g| g.lower_range == lower_range)
    }

    /// G(r + 1) / G(r) as the conversion uses it, its relative standard uncertainty, and
    /// whether it was calibrated (else the handshake's nominal value and
    /// [`Calibration::nominal_gain_ratio_relative_uncertainty`]).
    pub(crate) fn gain_ratio(&self, lower_range: u8) -> Result<(f64, f64, bool), CalibrationError> {
        if let Some(g) = self.calibrated_ratio(lower_range) {
            return Ok((g.ratio, g.relative_uncertainty, true));
        }
        let r = usize::from(lower_range);
        match (self.relative_gains.get(r), self.relative_gains.get(r + 1)) {
            (Some(&lo), Some(&hi)) => {
                Ok((hi / lo, self.nominal_gain_ratio_relative_uncertainty, false))
            }
            _ => Err(CalibrationError::NoRange(lower_range.saturating_add(1))),
        }
    }

    /// Gain of `range` relative to the most sensitive one: the product of the ratios below it.
    pub fn gain(&self, range: u8) -> Result<f64, CalibrationError> {
        let first = *self
            .relative_gains
            .first()
            .ok_or(CalibrationError::NoRange(range))?;
        if usize::from(range) >= self.relative_gains.len() {
            return Err(CalibrationError::NoRange(range));
        }
        (0..range).try_fold(first, |g, q| Ok(g * self.gain_ratio(q)?.0))
    }

    /// The standard deviation of one detector sample (block) on `range` at `net_counts`
    /// above dark, counts, from the calibration's own readings: the dark reading's scatter
    /// on that range (read noise) and the white readings' scatter beyond it (shot noise,
    /// whose variance grows with the signal and, for the same light, with the range's
    /// gain: on range r it is k·(g_r/g_w)·counts for k measured on the white's range w).
    /// A sweep's bin needs it: its few blocks were read while the signal changed, so
    /// their own scatter is the scene's slope as much as noise.
    ///
    /// Where the calibration read a steady scene on `range` itself (the white tile, or the
    /// sample for a gain ratio), the shot term is that range's own, measured: how the shot
    /// noise in counts scales from one range to another is the amplifier's, and assuming
    /// it (k ∝ gain) put the glossy peaks' bins on the least sensitive range at a fifth of
    /// their variance on the reference instrument, whose shot noise in counts is the same
    /// on every range. Only a range no steady reading was taken on is scaled by its gain.
    pub(crate) fn block_std_counts(
        &self,
        range: u8,
        net_counts: f64,
    ) -> Result<f64, CalibrationError> {
        let dark = self
            .dark
            .get(usize::from(range))
            .ok_or(CalibrationError::NoRange(range))?;
        let read_var = f64::from(dark.std_counts).powi(2);
        let steady = self
            .white
            .iter()
            .map(|w| &w.reading)
            .chain(
                self.gain_ratios
                    .iter()
                    .flat_map(|g| [&g.on_lower, &g.on_upper]),
            )
            .filter(|r| !r.saturated);
        let mut shot = Vec::new();
        for reading in steady {
            let r_dark = self
                .dark
                .get(usize::from(reading.range))
                .ok_or(CalibrationError::NoRange(reading.range))?;
            let net = self.net_counts(reading)?;
            if net > 0.0 {
                let excess =
                    f64::from(reading.std_counts).powi(2) - f64::from(r_dark.std_counts).powi(2);
                shot.push((excess.max(0.0) / net, reading.range));
            }
        }
        let own: Vec<f64> = shot
            .iter()
            .filter(|(_, r)| *r == range)
            .map(|(k, _)| *k)
            .collect();
        if !own.is_empty() {
            let per_count = own.iter().sum::<f64>() / own.len() as f64;
            return Ok((read_var + per_count * net_counts.max(0.0)).sqrt());
        }
        let per_count = if shot.is_empty() {
            0.0
        } else {
            let mut sum = 0.0;
            for &(k, white_range) in &shot {
                sum += k * self.gain(range)? / self.gain(white_range)?;
            }
            sum / shot.len() as f64
        };
        Ok((read_var + per_count * net_counts.max(0.0)).sqrt())
    }

    /// Counts above the dark of the reading's range, on that range.
    pub fn net_counts(&self, reading: &Reading) -> Result<f64, CalibrationError> {
        let dark = self
            .dark
            .get(usize::from(reading.range))
            .ok_or(CalibrationError::NoRange(reading.range))?;
        Ok(f64::from(reading.mean_counts) - f64::from(dark.mean_counts))
    }

    /// G(r + 1) / G(r) from one scene read on both ranges (`on_lower` on r, `on_upper` on
    /// r + 1), and its relative standard uncertainty from the two readings' own noise.
    pub fn ratio_from_readings(
        &self,
        on_lower: &Reading,
        on_upper: &Reading,
    ) -> Result<(f64, f64), CalibrationError> {
        if on_lower.saturated || on_upper.saturated {
            return Err(CalibrationError::Saturated);
        }
        let (lower, upper) = (self.net_counts(on_lower)?, self.net_counts(on_upper)?);
        if !(lower > 0.0 && upper > 0.0) {
            return Err(CalibrationError::Invalid(format!(
                "gain ratio of ranges {}/{}: the scene is not above dark on both ({lower:.1} and {upper:.1} counts)",
                on_lower.range, on_upper.range
            )));
        }
        let relative = (standard_error_counts(on_lower) / lower)
            .hypot(standard_error_counts(on_upper) / upper);
        Ok((upper / lower, relative))
    }

    /// How a sample reading at `theta_i_deg` converts.
    pub(crate) fn convert(
        &self,
        theta_i_deg: f64,
        reading: &Reading,
    ) -> Result<Conversion, CalibrationError> {
        if reading.saturated {
            return Err(CalibrationError::Saturated);
        }
        let (white_index, white) = self
            .white_at(theta_i_deg)
            .ok_or(CalibrationError::NoWhite(theta_i_deg))?;
        let net = self.net_counts(reading)?;
        let gain = self.gain(reading.range)?;
        let white_net = self.net_counts(&white.reading)?;
        let white_gain = self.gain(white.reading.range)?;
        if white_net <= 0.0 || white.reading.saturated {
            return Err(CalibrationError::WhiteNotAboveDark(theta_i_deg));
        }
        // Both in counts of the most sensitive range.
        let (s, w) = (net / gain, white_net / white_gain);
        let radiance_factor = s / w * self.white_radiance_factor;
        let per_count = self.white_radiance_factor / gain / w;
        // In the order folders already written used: a re-conversion must give their
        // readings to the last bit (gonio verify compares them).
        let own_std = standard_error_counts(reading) / gain / w * self.white_radiance_factor;
        Ok(Conversion {
            radiance_factor,
            own_std,
            net_counts: net,
            per_count,
            white_net_counts: white_net,
            range: reading.range,
            white_range: white.reading.range,
            white_index,
        })
    }

    /// Radiance factor of a sample reading at `theta_i_deg`, and its standard uncertainty
    /// from the reading's own noise (see the module's note on the shared errors).
    pub fn radiance_factor(
        &self,
        theta_i_deg: f64,
        reading: &Reading,
    ) -> Result<(f64, f64), CalibrationError> {
        self.convert(theta_i_deg, reading)
            .map(|c| (c.radiance_factor, c.own_std))
    }

    /// Whether the values can be right: what a file says is checked before it is used.
    pub fn validate(&self) -> Result<(), CalibrationError> {
        self.validate_field().map_err(|(_, e)| e)
    }

    /// [`Calibration::validate`], naming the field of `calibration.json` that is wrong
    /// (for a message at its line).
    pub(crate) fn validate_field(&self) -> Result<(), (&'static str, CalibrationError)> {
        let invalid = |key: &'static str, why: String| Err((key, CalibrationError::Invalid(why)));
        if let Err(e) = self.tile().validate() {
            let key = if e.to_string().contains("uncertainty") {
                "white_relative_uncertainty"
            } else {
                "white_radiance_factor"
            };
            return Err((key, e));
        }
        if self.relative_gains.is_empty()
            || self
                .relative_gains
                .iter()
                .any(|g| !(g.is_finite() && *g > 0.0))
        {
            return invalid(
                "relative_gains",
                format!(
                    "relative gains {:?} must be finite and positive",
                    self.relative_gains
                ),
            );
        }
        if self.dark.len() < self.relative_gains.len() {
            return invalid(
                "dark",
                format!(
                    "{} dark readings for {} ranges",
                    self.dark.len(),
                    self.relative_gains.len()
                ),
            );
        }
        let u = self.nominal_gain_ratio_relative_uncertainty;
        if !(u.is_finite() && (0.0..1.0).contains(&u)) {
            return invalid(
                "nominal_gain_ratio_relative_uncertainty",
                format!("nominal gain ratio uncertainty {u} is not in [0, 1)"),
            );
        }
        if !(self.lamp_drift_per_hour.is_finite() && (0.0..1.0).contains(&self.lamp_drift_per_hour))
        {
            return invalid(
                "lamp_drift_per_hour",
                format!(
                    "lamp drift {} per hour is not in [0, 1)",
                    self.lamp_drift_per_hour
                ),
            );
        }
        for g in &self.gain_ratios {
            let fine = g.ratio.is_finite()
                && g.ratio > 0.0
                && g.relative_uncertainty.is_finite()
                && g.relative_uncertainty >= 0.0
                && usize::from(g.lower_range) + 1 < self.relative_gains.len();
            if !fine {
                return invalid(
                    "gain_ratios",
                    format!(
                        "gain ratio of ranges {}/{} ({} ± {})",
                        g.lower_range,
                        u16::from(g.lower_range) + 1,
                        g.ratio,
                        g.relative_uncertainty
                    ),
                );
            }
        }
        if self
            .dark
            .iter()
            .any(|d| !(d.mean_counts.is_finite() && d.std_counts.is_finite()))
        {
            return invalid("dark", "a dark reading is not finite".into());
        }
        if self.white.is_empty() {
            return invalid("white", "no white reading".into());
        }
        for w in &self.white {
            let reading_fine =
                w.reading.mean_counts.is_finite() && w.reading.std_counts.is_finite();
            if !(w.theta_i_deg.is_finite() && reading_fine) {
                return invalid(
                    "white",
                    format!("white reading at θi = {}° is not finite", w.theta_i_deg),
                );
            }
            // A white reading no brighter than the dark converts nothing: every reading of
            // the sample at its incidence would fail, and be measured again for ever.
            if !w.reading.saturated && self.net_counts(&w.reading).is_ok_and(|net| !(net > 0.0)) {
                return invalid(
                    "white",
                    format!(
                        "the white reading at θi = {}° ({} counts) is not above the dark: no reading can be converted with it",
                        w.theta_i_deg, w.reading.mean_counts
                    ),
                );
            }
        }
        Ok(())
    }

    /// Age at `now_unix_s`.
    pub fn age(&self, now_unix_s: u64) -> Duration {
        Duration::from_secs(now_unix_s.saturating_sub(self.taken_unix_s))
    }

    /// The document of `calibration.json`: the calibration with its `schema`.
    pub(crate) fn to_document(&self) -> serde_json::Result<serde_json::Value> {
        Ok(crate::schema::tagged(
            crate::schema::CALIBRATION,
            serde_json::to_value(self)?,
        ))
    }

    /// The calibration of a `calibration.json` document (one without `schema` was written
    /// before gonio named its documents, and is read as this version).
    pub(crate) fn from_document(value: serde_json::Value) -> Result<Calibration, DocumentError> {
        crate::schema::check(
            &value,
            &[crate::schema::CALIBRATION],
            Some(crate::schema::CALIBRATION),
        )?;
        serde_json::from_value(value).map_err(DocumentError::NotCalibration)
    }

    /// [`Calibration::from_document`] of a file's text.
    pub(crate) fn from_json(text: &str) -> Result<Calibration, DocumentError> {
        let value: serde_json::Value =
            serde_json::from_str(text).map_err(DocumentError::NotJson)?;
        Calibration::from_document(value)
    }
}

/// Why a `calibration.json` document cannot be read.
#[derive(Debug, thiserror::Error)]
pub(crate) enum DocumentError {
    /// The text is not JSON.
    #[error("not JSON: {0}")]
    NotJson(serde_json::Error),
    /// Its `schema` is not the calibration's.
    #[error(transparent)]
    Schema(#[from] crate::schema::SchemaError),
    /// JSON, but not a calibration.
    #[error("not a calibration: {0}")]
    NotCalibration(serde_json::Error),
}

impl DocumentError {
    /// The line of the file where it went wrong, when known.
    pub fn line(&self) -> Option<usize> {
        match self {
            DocumentError::NotJson(e) => Some(e.line()),
            DocumentError::Schema(_) | DocumentError::NotCalibration(_) => None,
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A reading of 100 samples, 10 counts' scatter (the instrument layer's tests too).
    pub(crate) fn reading(mean_counts: f32, range: u8) -> Reading {
        Reading {
            mean_counts,
            std_counts: 10.0,
            samples: 100,
            range,
            integration_ms: 100,
            saturated: false,
        }
    }

    fn calibration() -> Calibration {
        Calibration::taken_at(
            1_000,
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

    #[test]
    fn converts_across_ranges_with_its_own_noise_only() {
        let c = calibration();
        // Half the white signal on range 0: R = 0.495.
        let (r, u) = c.radiance_factor(20.0, &reading(13_200.0, 0)).unwrap();
        assert!((r - 0.495).abs() < 1e-12);
        // Own noise: 10 counts / √100 over the white's 26 000 net counts, times 0.99.
        assert!((u - 1.0 / 26_000.0 * 0.99).abs() < 1e-12, "{u}");
        // Twenty times the white signal, read on range 2 (gain 0.01): R = 19.8.
        let (r, u) = c
            .radiance_factor(20.0, &reading(200.0 + 5_200.0, 2))
            .unwrap();
        assert!((r - 19.8).abs() < 1e-9, "{r}");
        assert!((u - 100.0 / 26_000.0 * 0.99).abs() < 1e-9, "{u}");
    }

    #[test]
    fn calibrated_ratios_replace_the_nominal_gains() {
        let mut c = calibration();
        assert_eq!(
            c.gain_ratio(0).unwrap(),
            (0.1, NOMINAL_GAIN_RATIO_RELATIVE_UNCERTAINTY, false)
        );
        let on = |m: f32, range: u8| reading(m, range);
        c.gain_ratios.push(GainRatio {
            lower_range: 1,
            ratio: 0.102,
            relative_uncertainty: 0.001,
            theta_i_deg: 60.0,
            theta_r_deg: 62.0,
            scene: "sample".into(),
            on_lower: on(50_000.0, 1),
            on_upper: on(5_300.0, 2),
            device_seconds: 1.0,
        });
        assert!((c.gain(2).unwrap() - 0.1 * 0.102).abs() < 1e-15);
        assert_eq!(c.gain(1).unwrap(), 0.1);
        let (r, _) = c
            .radiance_factor(20.0, &reading(200.0 + 5_200.0, 2))
            .unwrap();
        assert!((r - 19.8 / 1.02).abs() < 1e-9, "{r}");
        assert!(c.validate().is_ok());
        c.gain_ratios[0].lower_range = 2;
        assert!(matches!(c.validate(), Err(CalibrationError::Invalid(_))));
    }

    #[test]
    fn pooled_readings_weigh_by_their_noise() {
        let short = Reading {
            std_counts: 30.0,
            samples: 100,
            ..reading(1_000.0, 1)
        };
        let long = Reading {
            std_counts: 30.0,
            samples: 900,
            ..reading(1_100.0, 1)
        };
        let p = pool(&[short, long]).unwrap();
        // Weights 1 : 9.
        assert!(
            (f64::from(p.mean_counts) - 1_090.0).abs() < 1e-3,
            "{}",
            p.mean_counts
        );
        assert_eq!(p.samples, 1_000);
        assert!((standard_error_counts(&p) - 30.0 / 1000f64.sqrt()).abs() < 1e-4);
    }

    #[test]
    fn a_reading_without_noise_is_known_to_the_adcs_resolution() {
        let quiet = Reading {
            std_counts: 0.0,
            samples: 100,
            ..reading(1_000.0, 1)
        };
        assert_eq!(standard_error_counts(&quiet), RESOLUTION_STD_COUNTS);
        assert!((RESOLUTION_STD_COUNTS - 1.0 / 12f64.sqrt()).abs() < 1e-15);
        let noisy = Reading {
            std_counts: 30.0,
            samples: 100,
            ..reading(1_000.0, 1)
        };
        assert_eq!(
            standard_error_counts(&noisy),
            3.0,
            "above the floor a reading's own noise is its uncertainty"
        );
        assert!(
            standard_error_counts(&Reading {
                std_counts: f32::NAN,
                ..quiet
            })
            .is_nan()
        );
    }

    #[test]
    fn tile_certificates_are_checked() {
        assert_eq!(Tile::new(0.985, 0.4).unwrap().relative_uncertainty, 0.004);
        for (rf, pct) in [
            (0.0, 0.5),
            (1.5, 0.5),
            (f64::NAN, 0.5),
            (0.99, -1.0),
            (0.99, 60.0),
            (0.99, f64::INFINITY),
        ] {
            assert!(
                matches!(Tile::new(rf, pct), Err(CalibrationError::BadTile(_))),
                "{rf} {pct}"
            );
        }
    }

    /// A block's noise: the dark's scatter at dark, growing with the signal as the white's
    /// scatter says, and for the same light on a less sensitive range as its gain says.
    #[test]
    fn a_blocks_noise_follows_the_dark_and_white_readings() {
        let mut c = calibration();
        let dark = f64::from(c.dark[0].std_counts);
        assert!((c.block_std_counts(0, 0.0).unwrap() - dark).abs() < 1e-9);
        for w in &mut c.white {
            // 10 000 counts above a dark of 200 on range 0, scattered by 30 counts.
            w.reading = Reading {
                mean_counts: 10_200.0,
                std_counts: 30.0,
                samples: 100,
                range: 0,
                integration_ms: 100,
                saturated: false,
            };
        }
        let k = (900.0 - dark * dark) / 10_000.0;
        assert!((c.block_std_counts(0, 10_000.0).unwrap() - 30.0).abs() < 1e-6);
        assert!(
            (c.block_std_counts(0, 2_500.0).unwrap() - (dark * dark + k * 2_500.0).sqrt()).abs()
                < 1e-9
        );
        // Range 1 is 10× less sensitive: the same light gives a tenth of the counts and a
        // tenth of the shot variance per count.
        let on_1 = c.block_std_counts(1, 1_000.0).unwrap();
        let dark_1 = f64::from(c.dark[1].std_counts);
        assert!(
            (on_1 * on_1 - dark_1 * dark_1 - 0.1 * k * 1_000.0).abs() < 1e-6,
            "{on_1}"
        );
        assert!(c.block_std_counts(9, 1.0).is_err());
    }

    #[test]
    fn old_calibrations_load_with_the_stated_defaults() {
        let c = calibration();
        let mut value = serde_json::to_value(&c).unwrap();
        for key in [
            "white_relative_uncertainty",
            "nominal_gain_ratio_relative_uncertainty",
            "gain_ratios",
            "lamp_drift_per_hour",
        ] {
            value.as_object_mut().unwrap().remove(key);
        }
        let old: Calibration = serde_json::from_value(value).unwrap();
        assert_eq!(old, c);
    }

    #[test]
    fn a_maximum_age_is_a_number_of_hours_a_duration_holds() {
        assert_eq!(
            max_age_from_hours(8.0).unwrap(),
            Duration::from_secs(8 * 3600)
        );
        assert_eq!(
            max_age_from_hours(MAX_CALIBRATION_AGE_H).unwrap(),
            Duration::from_secs(8760 * 3600)
        );
        for bad in [
            f64::INFINITY,
            f64::NAN,
            -1.0,
            0.0,
            1e300,
            MAX_CALIBRATION_AGE_H + 1.0,
            f64::NEG_INFINITY,
        ] {
            let error = max_age_from_hours(bad).unwrap_err().to_string();
            assert!(
                error.contains("--max-calibration-age-h") && error.contains(&format!("{bad:?}")),
                "{error}"
            );
        }
    }

    #[test]
    fn refuses_what_it_cannot_convert() {
        let c = calibration();
        assert!(matches!(
            c.radiance_factor(30.0, &reading(1.0, 0)),
            Err(CalibrationError::NoWhite(_))
        ));
        assert!(matches!(
            c.radiance_factor(20.0, &reading(1.0, 3)),
            Err(CalibrationError::NoRange(3))
        ));
        let saturated = Reading {
            saturated: true,
            ..reading(65_535.0, 2)
        };
        assert!(matches!(
            c.radiance_factor(20.0, &saturated),
            Err(CalibrationError::Saturated)
        ));
    }
}
