//! A data set, the readings of one sample the fit takes, and the limits its numbers are
//! checked against, so that a typo gives an error at its line instead of an infinite or
//! NaN result: every number finite; |radiance factor| ≤ [`RADIANCE_FACTOR_MAX`] (10⁶:
//! far above any paper's specular peak seen through the detector's window, and its
//! square, weighted, stays far from overflow); a `std` in [[`STD_MIN`], [`STD_MAX`]]
//! (10⁻⁹ … 10⁶: its weight 1/std² stays finite), and within one data set the largest
//! `std` at most [`STD_RATIO_MAX`] (10⁶) times the smallest (weights within 10¹² of each
//! other, inside the 16 digits of an f64: beyond it the lighter readings would vanish
//! from the sums); a bin's travel within 0 … [`MAX_SPAN_DEG`]. The angles' range (0…90°)
//! and negative radiance factors are the fit's own checks. Reading them from CSV is
//! `output::dataset`'s.
// The fit's own limits, by their own names: a data set is read to exactly what the fit
// can weigh.
use crate::analysis::fit::{MAX_SPAN_DEG, Observation, RADIANCE_FACTOR_MAX, STD_MAX, STD_MIN};
use thiserror::Error;

/// The largest ratio of the largest to the smallest `std` in one data set.
pub(crate) const STD_RATIO_MAX: f64 = 1e6;

/// One data set: the readings of one sample, with the line each came from.
#[derive(Clone, Debug, PartialEq)]
pub struct DataSet {
    /// Sample name (the `sample` column, or the name given for files without one).
    pub sample: String,
    /// Readings in file order.
    pub observations: Vec<Observation>,
    /// 1-based line of each reading.
    pub lines: Vec<usize>,
}

impl DataSet {
    /// The (θi, θr) pairs, degrees.
    pub fn geometries(&self) -> Vec<(f64, f64)> {
        self.observations
            .iter()
            .map(|o| (o.theta_i_deg, o.theta_r_deg))
            .collect()
    }

    /// The positive uncertainties within [`STD_RATIO_MAX`] of each other.
    pub(crate) fn check_std_spread(&self) -> Result<(), StdSpread> {
        let positive = self
            .observations
            .iter()
            .zip(&self.lines)
            .filter_map(|(o, &line)| o.std.filter(|u| *u > 0.0).map(|u| (u, line)));
        // (std, line) of the smallest and of the largest.
        let mut low: Option<(f64, usize)> = None;
        let mut high: Option<(f64, usize)> = None;
        for (u, line) in positive {
            if low.is_none_or(|(l, _)| u < l) {
                low = Some((u, line));
            }
            if high.is_none_or(|(h, _)| u > h) {
                high = Some((u, line));
            }
        }
        match (low, high) {
            (Some((l, l_line)), Some((h, h_line))) if h > l * STD_RATIO_MAX => Err(StdSpread {
                line: h_line,
                value: h,
                other_line: l_line,
                other: l,
                sample: self.sample.clone(),
            }),
            _ => Ok(()),
        }
    }
}

/// Uncertainties of one data set too far apart to weigh them together.
#[derive(Clone, Debug, Error, PartialEq)]
#[error(
    "line {line}: std {value:?} is more than {STD_RATIO_MAX:e} times the std {other:?} of line {other_line} (sample '{}'): weights that far apart cannot be fitted together; check the units",
    crate::text::shown(.sample)
)]
pub struct StdSpread {
    /// Line of the largest std.
    pub line: usize,
    /// The largest std.
    pub value: f64,
    /// Line of the smallest std.
    pub(crate) other_line: usize,
    /// The smallest std.
    pub other: f64,
    /// The data set.
    pub sample: String,
}

/// Why a number of a reading cannot be fitted.
#[derive(Clone, Copy, Debug, Error, PartialEq, Eq)]
pub enum Unfittable {
    /// Infinite or NaN.
    #[error("not a finite number")]
    NotFinite,
    /// A radiance factor beyond ±[`RADIANCE_FACTOR_MAX`].
    #[error(
        "beyond ±{RADIANCE_FACTOR_MAX:e}, what the fit can represent (a paper's specular peak is below 10⁴)"
    )]
    RadianceFactor,
    /// A positive `std` outside [[`STD_MIN`], [`STD_MAX`]].
    #[error("outside {STD_MIN:e} … {STD_MAX:e}, what the fit can weigh")]
    Std,
    /// A bin's travel outside 0 … [`MAX_SPAN_DEG`].
    #[error("outside 0 … {MAX_SPAN_DEG}°, the detector's travel a bin can have")]
    Span,
}

/// A radiance factor the fit can represent.
pub(crate) fn check_radiance_factor(value: f64) -> Result<f64, Unfittable> {
    if value.abs() <= RADIANCE_FACTOR_MAX {
        Ok(value)
    } else {
        Err(Unfittable::RadianceFactor)
    }
}

/// A standard uncertainty the fit can weigh (0 and negative values pass: they are the
/// fit's `BadUncertainty`, named there).
pub(crate) fn check_std(std: f64) -> Result<f64, Unfittable> {
    if std <= 0.0 || (STD_MIN..=STD_MAX).contains(&std) {
        Ok(std)
    } else {
        Err(Unfittable::Std)
    }
}

/// A bin's travel (degrees) the detector can have.
pub(crate) fn check_span(span_deg: f64) -> Result<f64, Unfittable> {
    if (0.0..=MAX_SPAN_DEG).contains(&span_deg) {
        Ok(span_deg)
    } else {
        Err(Unfittable::Span)
    }
}
