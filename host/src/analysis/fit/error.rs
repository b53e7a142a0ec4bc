//! Why a data set cannot be fitted: every check of [`super::validation`] names the
//! reading and the value it refused.
use super::MAX_SPAN_DEG;
use thiserror::Error;

/// Why a data set cannot be fitted. `index` is the reading's position in the input slice.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum FitError {
    /// Fewer distinct geometries than model parameters.
    #[error(
        "only {found} distinct geometries: at least {needed} are needed to fit the {needed} parameters"
    )]
    TooFewGeometries {
        /// Distinct geometries found.
        found: usize,
        /// Parameters of the model.
        needed: usize,
    },
    /// A value is NaN or infinite.
    #[error("reading {index}: {what} is not a finite number")]
    NotFinite {
        /// Reading.
        index: usize,
        /// Which value.
        what: &'static str,
    },
    /// A negative radiance factor without an uncertainty to judge it by.
    #[error(
        "reading {index}: radiance factor {value} is negative (a reading may be below zero only within its standard uncertainty: give a std column)"
    )]
    Negative {
        /// Reading.
        index: usize,
        /// The value.
        value: f64,
    },
    /// A negative radiance factor further below zero than its uncertainty allows.
    #[error(
        "reading {index}: radiance factor {value} is negative, {k} standard uncertainties ({std}) below zero or more: not noise about a dark reading"
    )]
    NegativeBeyondNoise {
        /// Reading.
        index: usize,
        /// The value.
        value: f64,
        /// Its standard uncertainty.
        std: f64,
        /// [`super::validation::NEGATIVE_READING_STDS`].
        k: f64,
    },
    /// A radiance factor too large to be a reading.
    #[error("reading {index}: radiance factor {value} is above the largest accepted, {max:e}")]
    TooLarge {
        /// Reading.
        index: usize,
        /// The value.
        value: f64,
        /// [`super::RADIANCE_FACTOR_MAX`].
        max: f64,
    },
    /// An angle outside [0°, 90°).
    #[error(
        "reading {index}: {what} = {value}° is outside [0°, 90°) (at 90° the model's G/(cos θi·cos θr) is unbounded)"
    )]
    AngleOutOfRange {
        /// Reading.
        index: usize,
        /// `theta_i` or `theta_r`.
        what: &'static str,
        /// The angle.
        value: f64,
    },
    /// A detector travel that is no span a bin can have.
    #[error(
        "reading {index}: the detector's travel while it integrated, {value}°, is outside [0°, {MAX_SPAN_DEG}°]"
    )]
    SpanOutOfRange {
        /// Reading.
        index: usize,
        /// The span.
        value: f64,
    },
    /// A standard uncertainty that is not positive.
    #[error("reading {index}: standard uncertainty {value} is not positive")]
    BadUncertainty {
        /// Reading.
        index: usize,
        /// The value.
        value: f64,
    },
    /// A standard uncertainty outside [`super::STD_MIN`]…[`super::STD_MAX`].
    #[error(
        "reading {index}: standard uncertainty {value:e} is outside the accepted {min:e} … {max:e}"
    )]
    UncertaintyOutOfRange {
        /// Reading.
        index: usize,
        /// The value.
        value: f64,
        /// [`super::STD_MIN`].
        min: f64,
        /// [`super::STD_MAX`].
        max: f64,
    },
    /// Uncertainties for some readings but not all.
    #[error("reading {index} has no standard uncertainty while others have one")]
    MixedUncertainties {
        /// First reading without one.
        index: usize,
    },
    /// Every radiance factor is the same.
    #[error("all {n} radiance factors are equal ({value}): there is no shape to fit")]
    AllEqual {
        /// Readings.
        n: usize,
        /// The common value.
        value: f64,
    },
    /// Two readings at one geometry that disagree beyond their uncertainty.
    #[error(
        "readings {first} and {index} at the same geometry (θi {theta_i_deg}°, θr {theta_r_deg}°) conflict: {first_value} vs {value}"
    )]
    ConflictingDuplicates {
        /// Earlier reading.
        first: usize,
        /// Later reading.
        index: usize,
        /// θi, degrees.
        theta_i_deg: f64,
        /// θr, degrees.
        theta_r_deg: f64,
        /// Earlier value.
        first_value: f64,
        /// Later value.
        value: f64,
    },
    /// A shared error's sensitivity vector does not have one entry per reading.
    #[error("shared error '{name}': {found} sensitivities for {expected} readings")]
    SharedErrorLength {
        /// The shared error.
        name: String,
        /// Its length.
        found: usize,
        /// Readings.
        expected: usize,
    },
    /// A shared error's sensitivity is not a finite number of at most [`super::RADIANCE_FACTOR_MAX`].
    #[error(
        "shared error '{name}', reading {index}: sensitivity {value} is not a finite number within ±{max:e}"
    )]
    SharedErrorValue {
        /// The shared error.
        name: String,
        /// Reading.
        index: usize,
        /// The value.
        value: f64,
        /// [`super::RADIANCE_FACTOR_MAX`].
        max: f64,
    },
    /// Shared errors given for readings without uncertainties: their size has no scale.
    #[error(
        "shared error '{name}' given, but the readings have no standard uncertainties to set it against"
    )]
    SharedErrorWithoutUncertainties {
        /// The shared error.
        name: String,
    },
}

impl FitError {
    /// The reading the error is about, if it is about one.
    pub fn reading_index(&self) -> Option<usize> {
        match self {
            FitError::NotFinite { index, .. }
            | FitError::Negative { index, .. }
            | FitError::NegativeBeyondNoise { index, .. }
            | FitError::TooLarge { index, .. }
            | FitError::AngleOutOfRange { index, .. }
            | FitError::SpanOutOfRange { index, .. }
            | FitError::BadUncertainty { index, .. }
            | FitError::UncertaintyOutOfRange { index, .. }
            | FitError::MixedUncertainties { index }
            | FitError::ConflictingDuplicates { index, .. }
            | FitError::SharedErrorValue { index, .. } => Some(*index),
            FitError::TooFewGeometries { .. }
            | FitError::AllEqual { .. }
            | FitError::SharedErrorLength { .. }
            | FitError::SharedErrorWithoutUncertainties { .. } => None,
        }
    }
}
