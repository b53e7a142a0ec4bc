//! A spot checked like a measurement before the library keeps it (issue 30, D6): every
//! number finite and in the fit's own range, the covariance of the determined parameters
//! symmetric, positive definite and of a size the instrument can produce. One record that
//! is not moves the evidence for every stock (the population's scatter is pooled), so a
//! record that fails is refused with the reason, whether it comes from `add` or `import`.
use crate::analysis::evidence::Spot;
use crate::analysis::fit::{RADIANCE_FACTOR_MAX, SIGMA_MAX_DEG, SIGMA_MIN_DEG};
use thiserror::Error;

/// The parameters of a spot, in the order of [`Spot::values`].
const NAMES: [&str; 3] = ["sigma_deg", "rho_s", "rho_d"];

/// The smallest relative standard deviation accepted. Every reading of the instrument
/// carries at least ~1e-4 relative noise (detector and source), and a sheet's fit rests on
/// at most a few thousand readings, so no parameter is known to better than ~1e-6 of
/// itself; a smaller one is a copying error or a forgery, and would make its stock's
/// likelihood a needle that decides any search.
pub const MIN_RELATIVE_SD: f64 = 1e-6;
/// The largest standard deviation accepted, relative to the value (or to 1° of σ, or 1 in
/// radiance factor, when the value is smaller): a parameter known only to within ten times
/// itself is not determined, and the fit reports such a one as null rather than a number.
pub const MAX_RELATIVE_SD: f64 = 10.0;
/// Largest relative asymmetry |c_ij − c_ji| / √(c_ii c_jj) accepted: a covariance is
/// symmetric by construction; the slack is for numbers rounded by another program.
const MAX_ASYMMETRY: f64 = 1e-6;
/// Smallest Cholesky pivot of the correlation matrix: below it the covariance is singular
/// to working precision (a correlation of ±1, or negative definite).
const MIN_PIVOT: f64 = 1e-9;

/// Why a spot is refused.
#[derive(Debug, Error, PartialEq)]
pub enum SpotError {
    /// A value or covariance entry that is NaN or infinite.
    #[error("a spot value or covariance is not a finite number")]
    NotFinite,
    /// A value outside the range the fit itself allows.
    #[error("{name} = {value:?} is outside the fit's range [{low:?}, {high:?}]")]
    OutOfRange {
        /// The parameter.
        name: &'static str,
        /// Its value.
        value: f64,
        /// The fit's lower bound.
        low: f64,
        /// The upper bound.
        high: f64,
    },
    /// A variance of a determined parameter that is implausible for the instrument.
    #[error(
        "the variance of {name} is {variance:?} for a value of {value:?}: implausible for the instrument, whose standard deviations lie between {MIN_RELATIVE_SD:?} and {MAX_RELATIVE_SD} times the value"
    )]
    Implausible {
        /// The parameter.
        name: &'static str,
        /// Its value.
        value: f64,
        /// Its variance.
        variance: f64,
    },
    /// A covariance that is not symmetric.
    #[error("the covariance is not symmetric ({row}, {col})")]
    NotSymmetric {
        /// The parameter of the row.
        row: &'static str,
        /// Of the column.
        col: &'static str,
    },
    /// A covariance that is not positive definite.
    #[error(
        "the covariance is not positive definite (a variance of 0 or less, or a correlation of ±1 or beyond)"
    )]
    NotPositiveDefinite,
}

/// The fit's own bounds of σ [deg], ρs and ρd: σ as the fit bounds it (Table 3); ρs and ρd
/// are at least 0 (the fit's lower bounds) and at most the largest radiance factor the
/// fit accepts as a reading, 10⁴ times any paper's.
fn range(k: usize) -> (f64, f64) {
    if k == 0 {
        (SIGMA_MIN_DEG, SIGMA_MAX_DEG)
    } else {
        (0.0, RADIANCE_FACTOR_MAX)
    }
}

/// Check `spot` as a measurement (module doc). Rows and columns of undetermined
/// parameters (value null) are not used by the evidence, so only their finiteness is
/// checked.
pub(crate) fn check_spot(spot: &Spot) -> Result<(), SpotError> {
    let finite = spot
        .values
        .iter()
        .flatten()
        .chain(spot.covariance.iter().flatten())
        .all(|x| x.is_finite());
    if !finite {
        return Err(SpotError::NotFinite);
    }
    let determined: Vec<(usize, f64)> = (0..3)
        .filter_map(|k| spot.values[k].map(|v| (k, v)))
        .collect();
    let c = &spot.covariance;
    for &(k, value) in &determined {
        let (low, high) = range(k);
        if !(low..=high).contains(&value) {
            return Err(SpotError::OutOfRange {
                name: NAMES[k],
                value,
                low,
                high,
            });
        }
        if !(c[k][k] > 0.0) {
            return Err(SpotError::NotPositiveDefinite);
        }
        let sd = c[k][k].sqrt();
        // 1e-3 is σ's lower bound and a thousandth of white in radiance factor; 1 is a
        // degree of σ and white: the scales below which a relative error means nothing.
        let plausible = sd >= MIN_RELATIVE_SD * value.abs().max(1e-3)
            && sd <= MAX_RELATIVE_SD * value.abs().max(1.0);
        if !plausible {
            return Err(SpotError::Implausible {
                name: NAMES[k],
                value,
                variance: c[k][k],
            });
        }
    }
    for (a, &(i, _)) in determined.iter().enumerate() {
        for &(j, _) in &determined[a + 1..] {
            let scale = (c[i][i] * c[j][j]).sqrt();
            if (c[i][j] - c[j][i]).abs() > MAX_ASYMMETRY * scale {
                return Err(SpotError::NotSymmetric {
                    row: NAMES[i],
                    col: NAMES[j],
                });
            }
        }
    }
    positive_definite(c, &determined)
}

/// Cholesky of the correlation matrix of the determined parameters: scaled so that the
/// pivots measure correlation, not units.
fn positive_definite(c: &[[f64; 3]; 3], determined: &[(usize, f64)]) -> Result<(), SpotError> {
    let idx: Vec<usize> = determined.iter().map(|&(k, _)| k).collect();
    let n = idx.len();
    let mut l = [[0.0; 3]; 3];
    for a in 0..n {
        for b in 0..=a {
            let (i, j) = (idx[a], idx[b]);
            let r = c[i][j] / (c[i][i] * c[j][j]).sqrt();
            let s = r - (0..b).map(|m| l[a][m] * l[b][m]).sum::<f64>();
            if a == b {
                if !(s > MIN_PIVOT) {
                    return Err(SpotError::NotPositiveDefinite);
                }
                l[a][a] = s.sqrt();
            } else {
                l[a][b] = s / l[b][b];
            }
        }
    }
    Ok(())
}
