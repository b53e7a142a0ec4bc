//! Least-squares fit of the TSL model (Akao et al., "Fitting") with the bounds of Table 3,
//! and what the data say about it: goodness of fit, the uncertainty budget, and what was
//! not determined.
//!
//! How: ρs and ρd enter linearly, so for any (σ, η) their best non-negative values follow in
//! closed form (variable projection). A grid over log σ × η with that closed form gives the
//! profile of the cost and its basins, which is what makes the glossy papers' multimodal
//! problem safe; Levenberg–Marquardt on all four parameters (σ as ln σ, so σ > 0 holds by
//! construction; the others by an active-set projection) then polishes the best basins.
//! The cost is generalised least squares, rᵀ Σ⁻¹ r with Σ = diag(std²) + Σ_k s_k s_kᵀ the
//! readings' covariance including the errors they share ([`SharedError`]; Woodbury, see
//! the engine submodule). The model is the whole TSL model averaged over the detector's window
//! ([`crate::analysis::model`]).
//!
//! After the fit, in order: what the data cannot determine is taken out of the model and
//! said so (no specular part; σ unresolved; η at a bound); an arm zero offset δ0
//! (θr → θr + δ0) is fitted when the data call for it (likelihood-ratio test at 1 %,
//! [`ARM_OFFSET_LR_CRITICAL`]); goodness of fit ([`crate::analysis::gof`]); the parameters'
//! covariance C = G Σ Gᵀ (G the estimator's linearised map), split into the independent
//! noise's and each shared error's share, widened when the model does not fit.
//!
//! **Widening under lack of fit.** When `lack-of-fit` is raised the covariance is multiplied
//! by k = max(1, χ²/ν) · max(1, (1 + ρ)/(1 − ρ)), ρ the residuals' pooled lag-1
//! autocorrelation (clamped to [0, 0.9]): the first factor is the Birge ratio (the misfit
//! read as extra noise of unknown size), the second the variance inflation of positively
//! correlated residuals (an AR(1) series of n readings carries the information of
//! n(1 − ρ)/(1 + ρ) independent ones), since a misfit leaves correlated runs that the first
//! factor alone would count as independent. Intervals are then Student-t on ν. A sandwich
//! estimate was not chosen: its per-reading "meat" rests on one residual each, unstable at
//! the 12–40 readings of the short schedules, and like the Birge ratio it still assumes
//! independent residuals. The widening is in the budget as its own term, `lack of fit`.
mod engine;

use crate::analysis::flags::Flag;
use crate::analysis::gof::{self, StructureTest};
use crate::analysis::linalg::{self, Square};
use crate::analysis::model::{ETA, PARAM_NAMES, Params, RHO_S, SIGMA};
use engine::{
    LmOutcome, Problem, global_fit, levenberg_marquardt, levenberg_marquardt_until, lower_bounds,
    params_of, upper_bounds, x_of,
};
use serde::Serialize;
use statrs::distribution::{ContinuousCDF, StudentsT};
use thiserror::Error;

/// Smallest σ the fit considers, degrees: far below what any sampling here resolves.
pub const SIGMA_MIN_DEG: f64 = 1e-3;
/// Upper bound of σ (Table 3), degrees.
pub const SIGMA_MAX_DEG: f64 = 90.0;
/// Lower bound of η (Table 3).
pub const ETA_MIN: f64 = 1.0;
/// Upper bound of η (Table 3).
pub const ETA_MAX: f64 = 3.0;
/// Parameters of the full model.
pub const N_PARAMS: usize = 4;
/// Largest radiance factor accepted: far above any paper's peak seen through a 1° window
/// (a glossy paper's is ~60), and small enough that squares and sums of residuals stay
/// finite with the smallest uncertainty.
pub const RADIANCE_FACTOR_MAX: f64 = 1e6;
/// Smallest standard uncertainty accepted (absolute, radiance factor): no detector
/// resolves 1e-9 of the white level, and below it the weights 1/std² lose their meaning.
pub const STD_MIN: f64 = 1e-9;
/// Largest standard uncertainty accepted.
pub const STD_MAX: f64 = 1e6;
/// Largest arm zero offset the fit looks for, degrees: more is a broken instrument, not
/// an offset to fit away.
pub const ARM_OFFSET_MAX_DEG: f64 = 3.0;
/// δ0 is fitted when the likelihood-ratio statistic (cost without δ0 − cost with it, in
/// units of the noise variance) exceeds χ²(1) at 99 %.
pub const ARM_OFFSET_LR_CRITICAL: f64 = 6.634_896_601_021_213;
/// The score statistic (the likelihood ratio's quadratic prediction from δ0 = 0) below
/// which the search for δ0 is not run (it costs a few refits). Over 675 fits of ideal and
/// slightly offset sheets (G, SG, PPC, J1, MC; full grid and Strategy 2; with and without
/// uncertainties) the likelihood ratio never exceeded 2.7 where the score was below 2,
/// far under [`ARM_OFFSET_LR_CRITICAL`]; for large offsets the two agree to 0.1 %.
const ARM_OFFSET_SCREEN: f64 = 2.0;
/// χ²(1) at 95 %: a profile within this (× residual variance) of the minimum is consistent.
const CHI2_1_95: f64 = 3.841_458_820_694_124;
/// χ²(3) at 95 %.
const CHI2_3_95: f64 = 7.814_727_903_251_178;
/// The widest detector travel a reading may have, degrees: a sweep's bin is a fraction of
/// a degree to a few degrees; beyond this it would average the specular peak away.
pub const MAX_SPAN_DEG: f64 = 20.0;
/// Standard normal quantile at 0.975.
const Z_975: f64 = 1.959_963_984_540_054;
/// Largest lag-1 autocorrelation used in the widening factor.
const WIDENING_MAX_LAG1: f64 = 0.9;

/// One reading: geometry in degrees, radiance factor, and optionally its standard uncertainty.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Observation {
    /// Incidence angle θi, degrees.
    pub theta_i_deg: f64,
    /// Detection angle θr, degrees.
    pub theta_r_deg: f64,
    /// Measured radiance factor.
    pub radiance_factor: f64,
    /// Standard uncertainty of the radiance factor, if known.
    pub std: Option<f64>,
    /// How far the detector arm moved in θr while the reading integrated, degrees (a
    /// sweep's bin; 0 for a reading taken with the arms still): the reading is the mean
    /// over θr ± span/2 of what the detector sees there ([`crate::analysis::model::evaluate_reading`]).
    pub theta_r_span_deg: f64,
}

/// An error shared by several readings (one draw for all of them): reading k's radiance
/// factor is off by `(sensitivity[k] + additive[k]) · ε` with ε ~ N(0, 1), the same ε for
/// every k.
#[derive(Clone, Debug, PartialEq)]
pub struct SharedError {
    /// What it is, for the budget ("white θi = 60°", "tile certificate", "gain range 2/1", "lamp drift").
    pub name: String,
    /// Per observation (same order and length as the observations), radiance factor per
    /// unit ε of the part that scales with the reading (a tile, a white, a gain ratio),
    /// stated at the reading: the fit re-evaluates it at its model ([`fit_with_shared`]).
    pub sensitivity: Vec<f64>,
    /// Per observation, radiance factor per unit ε of the part that does not scale with the
    /// reading (a dark offset, an arm zero error), used as it is; empty: none.
    pub additive: Vec<f64>,
}

impl SharedError {
    /// Reading k's whole sensitivity at the readings (scaling and additive parts).
    pub fn total(&self, k: usize) -> f64 {
        self.sensitivity.get(k).copied().unwrap_or(0.0)
            + self.additive.get(k).copied().unwrap_or(0.0)
    }
}

/// The name of the arm zero's term in the budget.
pub const ARM_ZERO: &str = "arm zero";

/// Standard uncertainty of the detector arm's zero that a session assumes unless told
/// otherwise, degrees: the zero is set at the home switch and by aligning the aperture, good
/// to about 8 microsteps of 0.0125°.
pub const DEFAULT_ARM_ZERO_UNCERTAINTY_DEG: f64 = 0.1;

/// One term of the uncertainty budget: its contribution to the variance of σ (deg²), ρs,
/// ρd and η. The terms add up to the diagonal of [`FitResult::covariance`].
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct BudgetTerm {
    /// `reading noise` (the independent part), a [`SharedError`]'s name, or `lack of fit`.
    pub name: String,
    /// Contribution to Var of σ (degrees), ρs, ρd, η (0 for what was not determined).
    pub variance: [f64; N_PARAMS],
}

/// Options of a fit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FitOptions {
    /// Full width of the detector's acceptance in θr, degrees; `None` or 0 leaves it out.
    pub acceptance_deg: Option<f64>,
    /// Levenberg–Marquardt iteration limit per start.
    pub max_iterations: usize,
    /// Test for an arm zero offset and fit it when the data call for it.
    pub arm_offset: bool,
    /// Standard uncertainty of the detector arm's zero, degrees: where the data do not call
    /// for a fitted offset, an offset of this size is a shared error of every reading
    /// (the [`ARM_ZERO`] term, ∂f/∂θr times it). 0: the zero is exact.
    pub arm_zero_uncertainty_deg: f64,
    /// Variance of the log of the readings' noise scale where that scale was estimated
    /// from the data (a sweep's bins scaled to their own scatter): the χ² test allows for
    /// it ([`gof::chi2_upper_tail_scaled`]). 0: the stated noise is taken as exact.
    pub noise_scale_log_variance: f64,
}

impl Default for FitOptions {
    /// Readings of unknown provenance: no arm zero error is assumed (a session states its
    /// instrument's, [`DEFAULT_ARM_ZERO_UNCERTAINTY_DEG`]).
    fn default() -> Self {
        FitOptions {
            acceptance_deg: Some(crate::analysis::model::DEFAULT_ACCEPTANCE_DEG),
            max_iterations: 200,
            arm_offset: true,
            arm_zero_uncertainty_deg: 0.0,
            noise_scale_log_variance: 0.0,
        }
    }
}

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
    /// A negative radiance factor.
    #[error("reading {index}: radiance factor {value} is negative")]
    Negative {
        /// Reading.
        index: usize,
        /// The value.
        value: f64,
    },
    /// A radiance factor too large to be a reading.
    #[error("reading {index}: radiance factor {value} is above the largest accepted, {max:e}")]
    TooLarge {
        /// Reading.
        index: usize,
        /// The value.
        value: f64,
        /// [`RADIANCE_FACTOR_MAX`].
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
    /// A standard uncertainty outside [`STD_MIN`]…[`STD_MAX`].
    #[error(
        "reading {index}: standard uncertainty {value:e} is outside the accepted {min:e} … {max:e}"
    )]
    UncertaintyOutOfRange {
        /// Reading.
        index: usize,
        /// The value.
        value: f64,
        /// [`STD_MIN`].
        min: f64,
        /// [`STD_MAX`].
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
    /// A shared error's sensitivity is not a finite number of at most [`RADIANCE_FACTOR_MAX`].
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
        /// [`RADIANCE_FACTOR_MAX`].
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

/// How the iteration ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Status {
    /// The cost stopped decreasing (relative change below 1e-10 or no downhill step left).
    Converged,
    /// The iteration limit was reached first.
    IterationLimit,
}

impl Status {
    /// As the JSON spells it (`converged`, `iteration_limit`): one spelling in every output.
    pub fn name(self) -> &'static str {
        match self {
            Status::Converged => "converged",
            Status::IterationLimit => "iteration_limit",
        }
    }
}

/// Which side of its range a parameter sits on.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Bound {
    /// The lower bound.
    Lower,
    /// The upper bound.
    Upper,
}

/// What the data did not determine, what was estimated from the data alone, and what was
/// done about it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(rename_all = "snake_case", tag = "kind")]
pub enum Note {
    /// η ended at a bound; it is reported at the bound and not fitted.
    EtaAtBound {
        /// The bound's value.
        eta: f64,
    },
    /// No specular part (ρs = 0 or η = 1, where F ≡ 0): σ and η mean nothing; only ρd is fitted.
    NoSpecularTerm,
    /// The cost is flat down to σ → 0: the sampling does not resolve the peak. σ is only
    /// known to be below `upper_deg`; ρs, ρd, η are fitted with the peak in its σ → 0 limit.
    /// Through a detector window only ρs·min(1, ~σ/a) is then determined, so ρs is not
    /// reported; `rho_s_lower` is its value at σ = `upper_deg`, the smallest the data allow.
    SigmaUnresolved {
        /// Largest σ the data allow (95 % profile), degrees.
        upper_deg: f64,
        /// ρs at σ = `upper_deg` (with a window), the lower limit of ρs.
        rho_s_lower: Option<f64>,
    },
    /// The normal matrix was singular at the optimum: no confidence intervals.
    SingularJacobian,
    /// As many parameters as geometries: no residual variance, no confidence intervals.
    NoDegreesOfFreedom,
    /// No standard uncertainties were given: the readings are weighted equally, the noise is
    /// estimated from the residuals (`std`, one reading's if it were the same for all) and
    /// the intervals from the heteroscedasticity-consistent sandwich (from `SANDWICH_MIN_DOF` degrees of freedom);
    /// there is no χ² test.
    NoiseFromResiduals {
        /// The estimated standard deviation of one reading.
        std: f64,
    },
    /// An arm zero offset was fitted: every θr is taken as θr + `deg`.
    ArmOffsetFitted {
        /// δ0, degrees.
        deg: f64,
        /// Its standard uncertainty, degrees.
        std_deg: f64,
        /// The likelihood-ratio statistic that called for it.
        lr: f64,
    },
    /// The model does not describe the data: the covariance was multiplied by `factor`.
    IntervalsWidened {
        /// The variance factor k.
        factor: f64,
    },
    /// Neither goodness-of-fit test could be made (no uncertainties and too few θr neighbours).
    FitNotTestable,
    /// η's 95 % interval reaches 1, where ρs = A/(η²−1) is unbounded: ρs is not identified,
    /// only known to be at least `rho_s_lower` (its value at η's upper limit).
    RhoSUnbounded {
        /// Lower limit of ρs.
        rho_s_lower: f64,
    },
}

impl std::fmt::Display for Note {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Note::EtaAtBound { eta } => write!(f, "η at its bound {eta}: held there, not fitted"),
            Note::NoSpecularTerm => {
                f.write_str("no specular part: only ρd fitted (σ, η meaningless)")
            }
            Note::SigmaUnresolved {
                upper_deg,
                rho_s_lower,
            } => {
                write!(
                    f,
                    "σ not resolved by the sampling: only known to be below {upper_deg:.3}°"
                )?;
                match rho_s_lower {
                    Some(r) => write!(
                        f,
                        "; through the detector window ρs is not determined either (≥ {r:.4})"
                    ),
                    None => Ok(()),
                }
            }
            Note::SingularJacobian => {
                f.write_str("singular normal matrix at the optimum: no confidence intervals")
            }
            Note::NoDegreesOfFreedom => {
                f.write_str("as many parameters as geometries: no confidence intervals")
            }
            Note::NoiseFromResiduals { std } => {
                write!(
                    f,
                    "no uncertainties given: the noise is estimated from the residuals (std {std:.3e} if equal for all readings; intervals allow it to differ between readings); no χ² test"
                )
            }
            Note::ArmOffsetFitted { deg, std_deg, lr } => {
                write!(
                    f,
                    "arm zero offset fitted: every θr taken as θr + δ0, δ0 = {deg:+.3}° ± {std_deg:.3}° (test statistic {lr:.1} > {ARM_OFFSET_LR_CRITICAL:.2})"
                )
            }
            Note::IntervalsWidened { factor } => {
                write!(
                    f,
                    "the model does not describe the data: intervals widened × {:.2} (variance × {factor:.2})",
                    factor.sqrt()
                )
            }
            Note::FitNotTestable => f.write_str(
                "goodness of fit not testable: no uncertainties and too few θr neighbours",
            ),
            Note::RhoSUnbounded { rho_s_lower } => {
                write!(
                    f,
                    "η's interval reaches 1, where ρs = A/(η²−1) is unbounded (A = ρs·(η²−1) the amplitude the data fix): ρs not identified, only ≥ {rho_s_lower:.4}"
                )
            }
        }
    }
}

/// Which parameters a fit estimated (as parameters or, for ρs with η at its lower
/// bound, as the amplitude ρs·(η² − 1)); see [`FitResult::not_identified`] for which of
/// them mean something.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FittedModel(pub [bool; N_PARAMS]);

impl FittedModel {
    /// Names of the fitted parameters, in the order σ, ρs, ρd, η.
    pub fn names(&self) -> Vec<&'static str> {
        (0..N_PARAMS)
            .filter(|&i| self.0[i])
            .map(|i| PARAM_NAMES[i])
            .collect()
    }

    /// Number of fitted parameters.
    pub fn count(&self) -> usize {
        self.0.iter().filter(|&&b| b).count()
    }
}

/// A parameter at one of its bounds.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct ActiveBound {
    /// Parameter name (`sigma`, `rho_s`, `rho_d`, `eta`).
    pub param: &'static str,
    /// Which bound.
    pub bound: Bound,
}

/// A parameter the data did not determine, and why. It is reported as null and used by
/// nothing downstream (class, nearest reference, comparison).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct NotIdentified {
    /// Parameter name.
    pub param: &'static str,
    /// Why.
    pub reason: &'static str,
}

/// The fitted arm zero offset.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct ArmOffset {
    /// δ0, degrees: the detector was at θr + δ0 when it said θr.
    pub deg: f64,
    /// Standard uncertainty, degrees.
    pub std_deg: f64,
    /// 95 % interval, degrees.
    pub ci95: (f64, f64),
    /// Likelihood-ratio statistic of the test that called for it.
    pub lr: f64,
}

/// The outcome of a fit.
#[derive(Clone, Debug, PartialEq)]
pub struct FitResult {
    /// Parameter values the fitted model uses (see [`FitResult::reported`] for which mean something).
    pub params: Params,
    /// Which parameters were estimated.
    pub model: FittedModel,
    /// 95 % confidence intervals (normal quantile for weighted fits, Student t on ν for
    /// unweighted or widened ones), clipped to the bounds; `None` for parameters not
    /// fitted or not identified, or when none can be given.
    pub ci95: [Option<(f64, f64)>; N_PARAMS],
    /// Whether each interval was clipped at a bound.
    pub ci_clipped: [bool; N_PARAMS],
    /// Covariance of (σ in degrees, ρs, ρd, η), arm offset marginalised, widened under lack of
    /// fit; rows and columns of parameters not fitted or not identified are 0.
    pub covariance: [[f64; N_PARAMS]; N_PARAMS],
    /// The covariance's diagonal by source; the terms add up to it.
    pub budget: Vec<BudgetTerm>,
    /// Parameters sitting on a bound.
    pub active_bounds: Vec<ActiveBound>,
    /// What the data did not determine, and how the result was reached.
    pub notes: Vec<Note>,
    /// The acceptance window modelled, degrees, if it was.
    pub acceptance_deg: Option<f64>,
    /// The arm zero offset, if the data called for one.
    pub arm_offset: Option<ArmOffset>,
    /// The statistic of the arm-offset test (likelihood ratio, or the score screen when the
    /// search was not needed); `None` when not tested.
    pub arm_offset_statistic: Option<f64>,
    /// Readings.
    pub n: usize,
    /// Weighted sum of squared residuals rᵀΣ⁻¹r (the objective).
    pub cost: f64,
    /// χ² = the cost for weighted fits; `None` without uncertainties.
    pub chi2: Option<f64>,
    /// Upper-tail p-value of χ² on `dof`; `None` without uncertainties or degrees of freedom.
    pub gof_p: Option<f64>,
    /// The residual-structure test, when it could be run.
    pub structure: Option<StructureTest>,
    /// The model does not describe the data (χ² or structure test below its level).
    pub lack_of_fit: bool,
    /// Factor k the covariance was multiplied by (1 unless `lack_of_fit`).
    pub variance_scale: f64,
    /// Without given uncertainties: the standard deviation of one reading estimated from
    /// the residuals.
    pub noise_from_residuals: Option<f64>,
    /// Residual variance used for the intervals (k, or k·s² without uncertainties).
    pub residual_variance: f64,
    /// Degrees of freedom, n − fitted parameters (the arm offset included).
    pub dof: usize,
    /// Normalised mean absolute error (Eq. 5–6).
    pub nmae: f64,
    /// Root mean square of the (unweighted) residuals.
    pub rms: f64,
    /// Levenberg–Marquardt iterations of the run that gave the result.
    pub iterations: usize,
    /// How the iteration ended.
    pub status: Status,
    /// Whether readings carried uncertainties (a weighted fit).
    pub weighted: bool,
    /// The fit's flags ([`Flag::LackOfFit`]).
    pub flags: Vec<Flag>,
}

impl FitResult {
    /// The parameters the data did not determine, with the reason.
    pub fn not_identified(&self) -> Vec<NotIdentified> {
        not_identified_of(&self.notes)
    }

    /// Whether parameter `index` was determined by the data.
    pub fn identified(&self, index: usize) -> bool {
        index < N_PARAMS
            && !self
                .not_identified()
                .iter()
                .any(|n| n.param == PARAM_NAMES[index])
    }

    /// A parameter's value if it means something: fitted, or held at a bound the data
    /// pushed it to; `None` for what was not identified ([`FitResult::not_identified`]).
    pub fn reported(&self, index: usize) -> Option<f64> {
        self.identified(index)
            .then(|| self.params.to_array()[index])
    }

    /// σ in degrees if it was resolved.
    pub fn sigma_deg(&self) -> Option<f64> {
        self.reported(SIGMA)
    }

    /// Upper limit of σ when the sampling does not resolve the peak.
    pub fn sigma_upper_deg(&self) -> Option<f64> {
        self.notes.iter().find_map(|n| match n {
            Note::SigmaUnresolved { upper_deg, .. } => Some(*upper_deg),
            _ => None,
        })
    }

    /// Lower limit of ρs when ρs is not identified but bounded below (σ unresolved through
    /// a window, or η's interval reaching 1).
    pub fn rho_s_lower(&self) -> Option<f64> {
        self.notes.iter().find_map(|n| match n {
            Note::SigmaUnresolved { rho_s_lower, .. } => *rho_s_lower,
            Note::RhoSUnbounded { rho_s_lower } => Some(*rho_s_lower),
            _ => None,
        })
    }

    /// Whether there is a specular part at all.
    pub fn has_specular_term(&self) -> bool {
        !self.notes.contains(&Note::NoSpecularTerm)
    }

    /// Standard uncertainty of a parameter (σ in degrees), if fitted and identified.
    pub fn std_error(&self, index: usize) -> Option<f64> {
        (self.model.0[index] && self.identified(index))
            .then(|| self.covariance[index][index].max(0.0).sqrt())
    }
}

/// What the notes of a fit say was not identified.
fn not_identified_of(notes: &[Note]) -> Vec<NotIdentified> {
    let mut out = Vec::new();
    let no_specular = notes.contains(&Note::NoSpecularTerm);
    if no_specular {
        out.push(NotIdentified {
            param: PARAM_NAMES[SIGMA],
            reason: "no specular part",
        });
        out.push(NotIdentified {
            param: "eta",
            reason: "no specular part",
        });
    }
    for note in notes {
        match note {
            Note::SigmaUnresolved { rho_s_lower, .. } => {
                out.push(NotIdentified {
                    param: PARAM_NAMES[SIGMA],
                    reason: "not resolved by the sampling (only an upper limit)",
                });
                if rho_s_lower.is_some() {
                    out.push(NotIdentified { param: "rho_s", reason: "σ unresolved: through the detector window only ρs·min(1, ~σ/a) is determined" });
                }
            }
            Note::EtaAtBound { eta } if *eta <= ETA_MIN && !no_specular => {
                out.push(NotIdentified {
                    param: "rho_s",
                    reason: "η at its lower bound 1: only ρs·(η²−1) is determined",
                });
            }
            Note::RhoSUnbounded { .. } => {
                out.push(NotIdentified { param: "rho_s", reason: "η's 95 % interval reaches 1, where ρs is unbounded: only a lower limit" });
            }
            _ => {}
        }
    }
    out
}

/// Best non-negative ρs, ρd at a fixed (σ, η), and the cost there.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LinearSolution {
    /// ρs.
    pub rho_s: f64,
    /// ρd.
    pub rho_d: f64,
    /// Weighted sum of squared residuals.
    pub cost: f64,
}

/// Check the input, naming the first problem: finite numbers, angles in [0°, 90°),
/// 0 ≤ radiance factor ≤ [`RADIANCE_FACTOR_MAX`], [`STD_MIN`] ≤ std ≤ [`STD_MAX`],
/// uncertainties for all readings or none, no contradicting repeats, enough geometries.
pub fn validate(observations: &[Observation]) -> Result<(), FitError> {
    let weighted = observations.first().is_some_and(|o| o.std.is_some());
    for (index, o) in observations.iter().enumerate() {
        for (what, value) in [("theta_i", o.theta_i_deg), ("theta_r", o.theta_r_deg)] {
            if !value.is_finite() {
                return Err(FitError::NotFinite { index, what });
            }
            if !(0.0..90.0).contains(&value) {
                return Err(FitError::AngleOutOfRange { index, what, value });
            }
        }
        if !(0.0..=MAX_SPAN_DEG).contains(&o.theta_r_span_deg) {
            return Err(FitError::SpanOutOfRange {
                index,
                value: o.theta_r_span_deg,
            });
        }
        if !o.radiance_factor.is_finite() {
            return Err(FitError::NotFinite {
                index,
                what: "radiance_factor",
            });
        }
        if o.radiance_factor < 0.0 {
            return Err(FitError::Negative {
                index,
                value: o.radiance_factor,
            });
        }
        if o.radiance_factor > RADIANCE_FACTOR_MAX {
            return Err(FitError::TooLarge {
                index,
                value: o.radiance_factor,
                max: RADIANCE_FACTOR_MAX,
            });
        }
        match o.std {
            Some(s) if !s.is_finite() => return Err(FitError::NotFinite { index, what: "std" }),
            Some(s) if s <= 0.0 => return Err(FitError::BadUncertainty { index, value: s }),
            Some(s) if !(STD_MIN..=STD_MAX).contains(&s) => {
                return Err(FitError::UncertaintyOutOfRange {
                    index,
                    value: s,
                    min: STD_MIN,
                    max: STD_MAX,
                });
            }
            None if weighted => return Err(FitError::MixedUncertainties { index }),
            Some(_) if !weighted => {
                // The first reading had none: it is the odd one out.
                return Err(FitError::MixedUncertainties { index: 0 });
            }
            _ => {}
        }
    }
    // Duplicates: repeated readings are fine, contradicting ones are not. Without
    // uncertainties "contradicting" means more than 10 % apart; with them, more than 5 σ.
    let mut order: Vec<usize> = (0..observations.len()).collect();
    order.sort_by(|&a, &b| {
        let (oa, ob) = (&observations[a], &observations[b]);
        oa.theta_i_deg
            .total_cmp(&ob.theta_i_deg)
            .then(oa.theta_r_deg.total_cmp(&ob.theta_r_deg))
            .then(a.cmp(&b))
    });
    let mut distinct = 0;
    for (k, &i) in order.iter().enumerate() {
        let same_as_previous = k > 0 && {
            let (p, o) = (&observations[order[k - 1]], &observations[i]);
            p.theta_i_deg == o.theta_i_deg && p.theta_r_deg == o.theta_r_deg
        };
        if !same_as_previous {
            distinct += 1;
            continue;
        }
        let (first, o) = (order[k - 1], &observations[i]);
        let p = &observations[first];
        let diff = (p.radiance_factor - o.radiance_factor).abs();
        let tolerance = match (p.std, o.std) {
            (Some(a), Some(b)) => 5.0 * a.hypot(b),
            _ => 0.1 * p.radiance_factor.max(o.radiance_factor),
        };
        if diff > tolerance {
            return Err(FitError::ConflictingDuplicates {
                first,
                index: i,
                theta_i_deg: o.theta_i_deg,
                theta_r_deg: o.theta_r_deg,
                first_value: p.radiance_factor,
                value: o.radiance_factor,
            });
        }
    }
    if distinct < N_PARAMS {
        return Err(FitError::TooFewGeometries {
            found: distinct,
            needed: N_PARAMS,
        });
    }
    let (lo, hi) = observations
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), o| {
            (lo.min(o.radiance_factor), hi.max(o.radiance_factor))
        });
    if lo == hi {
        return Err(FitError::AllEqual {
            n: observations.len(),
            value: lo,
        });
    }
    Ok(())
}

/// Check the shared errors against the (validated) readings: one finite sensitivity of at
/// most [`RADIANCE_FACTOR_MAX`] per reading, and readings with uncertainties.
pub fn validate_shared(
    observations: &[Observation],
    shared: &[SharedError],
) -> Result<(), FitError> {
    let weighted = observations.first().is_some_and(|o| o.std.is_some());
    for term in shared {
        if !weighted {
            return Err(FitError::SharedErrorWithoutUncertainties {
                name: term.name.clone(),
            });
        }
        if term.sensitivity.len() != observations.len() {
            return Err(FitError::SharedErrorLength {
                name: term.name.clone(),
                found: term.sensitivity.len(),
                expected: observations.len(),
            });
        }
        if !term.additive.is_empty() && term.additive.len() != observations.len() {
            return Err(FitError::SharedErrorLength {
                name: term.name.clone(),
                found: term.additive.len(),
                expected: observations.len(),
            });
        }
        let mut values = term.sensitivity.iter().chain(&term.additive).enumerate();
        if let Some((index, &value)) =
            values.find(|(_, v)| v.is_nan() || v.abs() > RADIANCE_FACTOR_MAX)
        {
            let index = index % observations.len().max(1);
            return Err(FitError::SharedErrorValue {
                name: term.name.clone(),
                index,
                value,
                max: RADIANCE_FACTOR_MAX,
            });
        }
    }
    Ok(())
}

/// The best non-negative ρs, ρd at a given (σ, η) and the cost there: the inner problem of
/// the fit, public so that a brute-force search can check the fit's global minimum.
pub fn linear_profile(
    observations: &[Observation],
    sigma_deg: f64,
    eta: f64,
    acceptance_deg: Option<f64>,
) -> Result<LinearSolution, FitError> {
    Ok(LinearProfile::new(observations, acceptance_deg)?.at(sigma_deg, eta))
}

/// [`linear_profile`] for many (σ, η) on the same readings, prepared once.
pub struct LinearProfile(Problem);

impl LinearProfile {
    /// Validate and prepare the readings.
    pub fn new(
        observations: &[Observation],
        acceptance_deg: Option<f64>,
    ) -> Result<LinearProfile, FitError> {
        validate(observations)?;
        Ok(LinearProfile(Problem::new(
            observations,
            &[],
            acceptance_deg,
            0.0,
        )))
    }

    /// The best non-negative ρs, ρd at (σ, η) and the cost there.
    pub fn at(&self, sigma_deg: f64, eta: f64) -> LinearSolution {
        self.0.linear(sigma_deg, eta)
    }
}

/// Weighted cost of given parameters (the fit's objective, independent noise only).
pub fn cost(observations: &[Observation], params: &Params, acceptance_deg: Option<f64>) -> f64 {
    let problem = Problem::new(observations, &[], acceptance_deg, 0.0);
    problem.accumulate(&x_of(params), false).0
}

/// Student t quantile at 0.975 for `dof` degrees of freedom (statrs); ∞ without any.
pub fn t_quantile_975(dof: usize) -> f64 {
    if dof == 0 {
        return f64::INFINITY;
    }
    StudentsT::new(0.0, 1.0, dof as f64).map_or(f64::INFINITY, |t| t.inverse_cdf(0.975))
}

/// Fit the TSL model to the readings (independent noise only).
pub fn fit(observations: &[Observation], options: &FitOptions) -> Result<FitResult, FitError> {
    fit_with_shared(observations, &[], options)
}

/// The shared errors as the fit uses them: each term's scaling part evaluated at the model's
/// `values` (s_ik · f̂_i / y_i, the ratio held within ½…2; `None`: at the readings) plus its
/// additive part, in one sensitivity.
fn at_model(
    shared: &[SharedError],
    observations: &[Observation],
    values: Option<&[f64]>,
) -> Vec<SharedError> {
    shared
        .iter()
        .map(|term| {
            let sensitivity = term
                .sensitivity
                .iter()
                .enumerate()
                .map(|(i, &s)| {
                    let y = observations[i].radiance_factor;
                    let scaled = match values.map(|v| v[i]) {
                        Some(f) if y > 0.0 && f > 0.0 => s * (f / y).clamp(0.5, 2.0),
                        _ => s,
                    };
                    scaled + term.additive.get(i).copied().unwrap_or(0.0)
                })
                .collect();
            SharedError {
                name: term.name.clone(),
                sensitivity,
                additive: Vec::new(),
            }
        })
        .collect()
}

/// Fit the TSL model to readings whose errors are partly shared: the covariance of the
/// readings is diag(std²) + Σ_k s_k s_kᵀ.
///
/// The scaling parts of the sensitivities are taken per unit of the reading: the fit
/// re-evaluates them at its own model values, s_ik · f̂_i / y_i, after a first pass (and
/// again at the shifted model when it accepts an arm offset). A covariance built from the
/// readings themselves (s = reading × relative uncertainty, all a budget can know before
/// the fit) pulls the estimate towards the low readings, which get the smaller errors
/// (Peelle's pertinent puzzle: −2 % on ρd with a 1 % tile error over 284 readings);
/// evaluated at the model, the covariance no longer depends on the noise of the readings.
/// The additive parts (a dark offset) are used as they are: scaled by f̂/y they came out up
/// to 2× or ½× on a shifted peak's flanks, where the first pass's model is far from the
/// readings.
///
/// With [`FitOptions::arm_zero_uncertainty_deg`] and no fitted offset, the arm zero's
/// possible offset is one more shared error, ∂f/∂θr at the model times its uncertainty: a
/// 0.1° zero error is below what the offset test can see on a rough paper's 12 readings,
/// yet it moved J1's σ by 2–3 standard errors (its interval covered the truth in 28 % of
/// sessions).
pub fn fit_with_shared(
    observations: &[Observation],
    shared: &[SharedError],
    options: &FitOptions,
) -> Result<FitResult, FitError> {
    validate(observations)?;
    validate_shared(observations, shared)?;
    let acceptance = options.acceptance_deg.filter(|&a| a > 0.0);
    let given = shared;
    let mut shared: Vec<SharedError> = if given.is_empty() {
        Vec::new()
    } else {
        let first = Problem::new(
            observations,
            &at_model(given, observations, None),
            acceptance,
            0.0,
        );
        let values = first.values(&global_fit(&first, options.max_iterations).x);
        at_model(given, observations, Some(&values))
    };
    let n = observations.len();
    let weighted = observations[0].std.is_some();
    let mut problem = Problem::new(observations, &shared, acceptance, 0.0);
    let mut outcome = global_fit(&problem, options.max_iterations);
    let mut notes = Vec::new();
    let mut fitted = [true; 4];
    let lo = lower_bounds();
    let hi = upper_bounds();
    let residual_variance = |cost: f64, p: usize| {
        if weighted {
            1.0
        } else {
            cost / (n.saturating_sub(p).max(1)) as f64
        }
    };

    // Is there a specular part at all? A lobe that improves on a constant by less than
    // χ²(3) at 95 % (× residual variance) is noise being fitted: the three extra
    // parameters are not supported.
    let lambert_cost = problem
        .accumulate(&[0.0, 0.0, problem.lambert(), ETA_MAX], false)
        .0;
    let no_lobe = (lambert_cost - outcome.cost) <= CHI2_3_95 * residual_variance(outcome.cost, 4);
    let mut unresolved = false;
    if no_lobe || outcome.x[RHO_S] <= lo[RHO_S] {
        // F ≡ 0 or ρs = 0: the specular part is absent and only ρd remains.
        notes.push(Note::NoSpecularTerm);
        fitted = [false, false, true, false];
        let x = [outcome.x[0], 0.0, problem.lambert(), ETA_MAX];
        outcome = LmOutcome {
            x,
            cost: problem.accumulate(&x, false).0,
            ..outcome
        };
    } else {
        // Is the peak resolved? Compare with the σ → 0 limit, others refitted.
        let s2 = residual_variance(outcome.cost, 4).max(1e-300);
        let threshold = outcome.cost + CHI2_1_95 * s2;
        let sigma_hat = outcome.x[0].exp();
        if sigma_hat < 10.0 {
            // Screen: ρs, ρd solved exactly at σ → 0 and the fitted η. A resolved peak is
            // orders of magnitude worse there; only a close call needs the full refit.
            let screen = problem.linear(SIGMA_MIN_DEG, outcome.x[ETA]).cost;
            let close_call = screen - outcome.cost <= 100.0 * (threshold - outcome.cost)
                || screen <= 2.0 * outcome.cost;
            let mut x_floor = outcome.x;
            x_floor[0] = lo[0];
            if close_call {
                // ρs at the floor from the closed form (through a window it must grow as
                // 1/σ to keep the specular readings), then the reduced fit to the threshold.
                let start = problem.linear(SIGMA_MIN_DEG, outcome.x[ETA]);
                x_floor[1] = start.rho_s * engine::eta_factor(outcome.x[ETA]);
                x_floor[2] = start.rho_d;
                let floor = levenberg_marquardt_until(
                    &problem,
                    x_floor,
                    [true, false, false, false],
                    options.max_iterations,
                    threshold,
                );
                if floor.cost <= threshold {
                    unresolved = true;
                    let (upper, x_upper) =
                        sigma_upper_deg(&problem, &outcome, threshold, options.max_iterations);
                    let rho_s_lower = acceptance.map(|_| params_of(&x_upper).rho_s);
                    notes.push(Note::SigmaUnresolved {
                        upper_deg: upper,
                        rho_s_lower,
                    });
                    fitted[SIGMA] = false;
                    // The screen stopped at the threshold: finish the reduced fit.
                    outcome = levenberg_marquardt(
                        &problem,
                        floor.x,
                        [true, false, false, false],
                        options.max_iterations,
                    );
                }
            }
        }
    }

    // Arm zero offset: only where the peak is resolved (an unresolved peak's position is
    // confounded with σ; without a peak there is nothing to shift).
    let mut arm_offset_statistic = None;
    let mut arm_fitted = false;
    if options.arm_offset && !unresolved && fitted[RHO_S] {
        let fitted_count = fitted.iter().filter(|&&b| b).count();
        let search = arm_offset_search(
            observations,
            &shared,
            acceptance,
            &problem,
            &outcome,
            fitted_count,
            options.max_iterations,
        );
        arm_offset_statistic = Some(search.statistic);
        if let Some((shifted, refit)) = search.accepted {
            if given.is_empty() {
                (problem, outcome) = (shifted, refit);
            } else {
                // The scaling parts were evaluated at the first pass's model, which had no
                // offset: evaluated again at the shifted model, and the fit redone with them.
                let values = shifted.values(&refit.x);
                shared = at_model(given, observations, Some(&values));
                problem = Problem::new(observations, &shared, acceptance, shifted.shift_deg);
                outcome =
                    levenberg_marquardt(&problem, refit.x, [false; 4], options.max_iterations);
            }
            arm_fitted = true;
        }
    }
    // An offset too small for the test to call for is still possible: the arm zero's
    // uncertainty as a shared error, at the model, and the fit redone with it.
    if options.arm_zero_uncertainty_deg > 0.0
        && options.arm_zero_uncertainty_deg.is_finite()
        && !arm_fitted
        && !unresolved
        && fitted[RHO_S]
        && weighted
    {
        let u = options.arm_zero_uncertainty_deg;
        let whitened = problem.shift_column(&outcome.x);
        let additive: Vec<f64> = whitened
            .iter()
            .zip(observations)
            .map(|(d, o)| d * o.std.unwrap_or(1.0) * u)
            .collect();
        if additive.iter().all(|v| v.is_finite()) && additive.iter().any(|v| *v != 0.0) {
            shared.push(SharedError {
                name: ARM_ZERO.to_string(),
                sensitivity: additive,
                additive: Vec::new(),
            });
            problem = Problem::new(observations, &shared, acceptance, 0.0);
            let fixed = std::array::from_fn(|i| !fitted[i]);
            outcome = levenberg_marquardt(&problem, outcome.x, fixed, options.max_iterations);
        }
    }
    let shared = &shared[..];

    if fitted[RHO_S] {
        if outcome.x[ETA] >= hi[ETA] {
            notes.push(Note::EtaAtBound { eta: ETA_MAX });
            fitted[ETA] = false;
        } else if outcome.x[ETA] <= lo[ETA] {
            // η → 1: F ∝ (η²−1), so only the amplitude ρs·(η²−1) is determined, not ρs.
            notes.push(Note::EtaAtBound { eta: ETA_MIN });
            fitted[ETA] = false;
        }
    }

    let x = outcome.x;
    let params = params_of(&x);
    let cost = problem.accumulate(&x, false).0;
    let mut active_bounds = Vec::new();
    let mut free = fitted;
    for i in 0..4 {
        if !fitted[i] {
            continue;
        }
        if x[i] <= lo[i] {
            active_bounds.push(ActiveBound {
                param: PARAM_NAMES[i],
                bound: Bound::Lower,
            });
            free[i] = false;
        } else if x[i] >= hi[i] {
            active_bounds.push(ActiveBound {
                param: PARAM_NAMES[i],
                bound: Bound::Upper,
            });
            free[i] = false;
        }
    }
    for note in &notes {
        if let Note::EtaAtBound { eta } = note {
            let bound = if *eta >= ETA_MAX {
                Bound::Upper
            } else {
                Bound::Lower
            };
            active_bounds.push(ActiveBound {
                param: "eta",
                bound,
            });
        }
    }
    let model = FittedModel(fitted);
    let dof = n.saturating_sub(model.count() + usize::from(arm_fitted));

    // Goodness of fit.
    let (residuals, jacobian) = problem.rows(&x);
    let (chi2, gof_p, s2, noise_from_residuals) = if weighted {
        (
            Some(cost),
            gof::chi2_upper_tail_scaled(cost, dof, options.noise_scale_log_variance),
            1.0,
            None,
        )
    } else if dof > 0 {
        let s2 = cost / dof as f64;
        notes.push(Note::NoiseFromResiduals { std: s2.sqrt() });
        (None, None, s2, Some(s2.sqrt()))
    } else {
        (None, None, f64::NAN, None)
    };
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| {
        let (oa, ob) = (&observations[a], &observations[b]);
        oa.theta_i_deg
            .total_cmp(&ob.theta_i_deg)
            .then(oa.theta_r_deg.total_cmp(&ob.theta_r_deg))
            .then(a.cmp(&b))
    });
    let decorrelated = gof::innovations(&residuals, &problem.shared.s, problem.shared.m, &order);
    let theta_i_sorted: Vec<f64> = order.iter().map(|&i| observations[i].theta_i_deg).collect();
    let structure = gof::structure_test(&theta_i_sorted, &decorrelated);
    let lack_of_fit = gof_p.is_some_and(|p| p < gof::GOF_ALPHA)
        || structure.is_some_and(|s| s.p_value < gof::STRUCTURE_ALPHA);
    if gof_p.is_none() && structure.is_none() && dof > 0 {
        notes.push(Note::FitNotTestable);
    }
    let variance_scale = if lack_of_fit {
        let birge = chi2.map_or(1.0, |c| (c / dof.max(1) as f64).max(1.0));
        let rho = structure.map_or(0.0, |s| s.lag1.clamp(0.0, WIDENING_MAX_LAG1));
        birge * ((1.0 + rho) / (1.0 - rho))
    } else {
        1.0
    };
    if variance_scale > 1.0 {
        notes.push(Note::IntervalsWidened {
            factor: variance_scale,
        });
    }

    // Covariance C = G Σ Gᵀ over the free parameters in x = (ln σ, A, ρd, η) and δ0, split
    // into the independent noise's share and each shared error's.
    let free_index: Vec<usize> = (0..4).filter(|&i| free[i]).collect();
    let mut columns: Vec<Vec<f64>> = free_index
        .iter()
        .map(|&i| jacobian.iter().map(|row| row[i]).collect())
        .collect();
    if arm_fitted {
        columns.push(problem.shift_column(&x));
    }
    let p = columns.len();
    let mut covariance = [[0.0; 4]; 4];
    let mut ci95 = [None; 4];
    let mut ci_clipped = [false; 4];
    let mut budget = Vec::new();
    let mut arm_offset = None;
    let mut terms_x: Vec<(String, Square)> = Vec::new();
    let mut total_x: Option<Square> = None;
    if dof == 0 {
        notes.push(Note::NoDegreesOfFreedom);
    } else if p > 0 {
        let normal = gls_normal(&problem.shared, &columns, None);
        match linalg::spd_inverse(&normal.h) {
            None => notes.push(Note::SingularJacobian),
            Some(h_inv) => {
                let m = problem.shared.m;
                let mut independent = h_inv.clone();
                let l_inv = linalg::lower_inverse(&problem.shared.l);
                let mut shared_terms = Vec::with_capacity(m);
                for (k, term) in shared.iter().enumerate() {
                    // G s_k = H⁻¹ Xᵀ Σ⁻¹ s_k = H⁻¹ P'ᵀ (L⁻¹ e_k), P' = L⁻¹ S̃ᵀ X.
                    let c: Vec<f64> = (0..m).map(|r| l_inv.at(r, k)).collect();
                    let xt: Vec<f64> = (0..p)
                        .map(|col| (0..m).map(|r| normal.pl[r][col] * c[r]).sum())
                        .collect();
                    let v: Vec<f64> = (0..p)
                        .map(|i| (0..p).map(|j| h_inv.at(i, j) * xt[j]).sum())
                        .collect();
                    let mut outer = Square::zeros(p);
                    for i in 0..p {
                        for j in 0..p {
                            *outer.at_mut(i, j) = v[i] * v[j];
                            *independent.at_mut(i, j) -= v[i] * v[j];
                        }
                    }
                    shared_terms.push((term.name.clone(), outer));
                }
                let scale = |mut s: Square, f: f64| {
                    s.a.iter_mut().for_each(|v| *v *= f);
                    s
                };
                let (noise_name, noise) = if weighted {
                    ("reading noise", independent)
                } else if dof >= SANDWICH_MIN_DOF {
                    (
                        "reading noise (estimated from the residuals)",
                        sandwich(&h_inv, &columns, &residuals),
                    )
                } else {
                    (
                        "reading noise (estimated from the residuals)",
                        scale(independent, s2),
                    )
                };
                // Weighted: H⁻¹ = G Σ Gᵀ, the noise's and the shared terms' shares together.
                let total = if weighted {
                    scale(h_inv, variance_scale)
                } else {
                    scale(noise.clone(), variance_scale)
                };
                terms_x.push((noise_name.to_string(), noise));
                terms_x.extend(shared_terms);
                if variance_scale > 1.0 {
                    terms_x.push((
                        "lack of fit".to_string(),
                        scale(total.clone(), (variance_scale - 1.0) / variance_scale),
                    ));
                }
                total_x = Some(total);
            }
        }
    }
    if let Some(total) = &total_x {
        // d(σ, ρs, ρd, η)/d(ln σ, A, ρd, η): σ = e^x0, ρs = A/(η²−1); δ0 enters none.
        let k = engine::eta_factor(x[3]);
        let mut jac_full = [[0.0; 4]; 4];
        jac_full[0][0] = params.sigma_deg;
        jac_full[1][1] = 1.0 / k;
        jac_full[1][3] = -x[1] * 2.0 * x[3] / (k * k);
        jac_full[2][2] = 1.0;
        jac_full[3][3] = 1.0;
        let jac: Vec<[f64; 4]> = (0..p)
            .map(|c| {
                std::array::from_fn(|r| {
                    if c < free_index.len() {
                        jac_full[r][free_index[c]]
                    } else {
                        0.0
                    }
                })
            })
            .collect();
        let to_natural = |s: &Square| -> [[f64; 4]; 4] {
            std::array::from_fn(|r| {
                std::array::from_fn(|c| {
                    let mut sum = 0.0;
                    for a in 0..p {
                        for b in 0..p {
                            sum += jac[a][r] * s.at(a, b) * jac[b][c];
                        }
                    }
                    sum
                })
            })
        };
        let quantile = if weighted && variance_scale == 1.0 {
            Z_975
        } else {
            t_quantile_975(dof)
        };
        let full = to_natural(total);
        // ρs = A/(η²−1) is unbounded above when η's interval reaches 1: then it is not
        // identified, and only bounded below (by its value at η's upper limit).
        if free[ETA] && free[RHO_S] {
            let se_eta = full[ETA][ETA].max(0.0).sqrt();
            if x[ETA] - quantile * se_eta <= engine::ETA_FLOOR {
                let eta_hi = (x[ETA] + quantile * se_eta).min(ETA_MAX);
                notes.push(Note::RhoSUnbounded {
                    rho_s_lower: x[RHO_S] / engine::eta_factor(eta_hi),
                });
            }
        }
        let not_identified = not_identified_of(&notes);
        let unknown: Vec<usize> = (0..4)
            .filter(|&i| not_identified.iter().any(|u| u.param == PARAM_NAMES[i]))
            .collect();
        let zero_unknown = |m: [[f64; 4]; 4]| -> [[f64; 4]; 4] {
            std::array::from_fn(|r| {
                std::array::from_fn(|c| {
                    if unknown.contains(&r) || unknown.contains(&c) {
                        0.0
                    } else {
                        m[r][c]
                    }
                })
            })
        };
        covariance = zero_unknown(full);
        for (name, term) in &terms_x {
            let natural = zero_unknown(to_natural(term));
            budget.push(BudgetTerm {
                name: name.clone(),
                variance: std::array::from_fn(|i| natural[i][i]),
            });
        }
        let natural_lo = [SIGMA_MIN_DEG, 0.0, 0.0, ETA_MIN];
        let natural_hi = [SIGMA_MAX_DEG, f64::INFINITY, f64::INFINITY, ETA_MAX];
        for (c, &i) in free_index.iter().enumerate() {
            if unknown.contains(&i) {
                continue;
            }
            let v = params.to_array()[i];
            let (low, high) = if i == SIGMA {
                // In ln σ, so the interval stays positive and follows the lobe's scale.
                let se = total.at(c, c).max(0.0).sqrt();
                ((x[0] - quantile * se).exp(), (x[0] + quantile * se).exp())
            } else if i == RHO_S && v > 0.0 {
                // In ln ρs too: ρs = A/(η²−1) is a ratio whose uncertainty is relative.
                let se = covariance[i][i].max(0.0).sqrt() / v;
                (v * (-quantile * se).exp(), v * (quantile * se).exp())
            } else {
                let se = covariance[i][i].max(0.0).sqrt();
                (v - quantile * se, v + quantile * se)
            };
            let (cl, ch) = (low.max(natural_lo[i]), high.min(natural_hi[i]));
            ci_clipped[i] = cl != low || ch != high;
            ci95[i] = Some((cl, ch));
        }
        if arm_fitted {
            let se = total.at(p - 1, p - 1).max(0.0).sqrt();
            let deg = problem.shift_deg;
            let lr = arm_offset_statistic.unwrap_or(f64::NAN);
            arm_offset = Some(ArmOffset {
                deg,
                std_deg: se,
                ci95: (deg - quantile * se, deg + quantile * se),
                lr,
            });
            notes.push(Note::ArmOffsetFitted {
                deg,
                std_deg: se,
                lr,
            });
        }
    } else if arm_fitted {
        let lr = arm_offset_statistic.unwrap_or(f64::NAN);
        let deg = problem.shift_deg;
        arm_offset = Some(ArmOffset {
            deg,
            std_deg: f64::NAN,
            ci95: (f64::NAN, f64::NAN),
            lr,
        });
        notes.push(Note::ArmOffsetFitted {
            deg,
            std_deg: f64::NAN,
            lr,
        });
    }

    let values = problem.values(&x);
    let (mut abs_sum, mut sq_sum) = (0.0, 0.0);
    let (mut y_min, mut y_max) = (f64::INFINITY, f64::NEG_INFINITY);
    for (f, o) in values.iter().zip(observations) {
        let r = f - o.radiance_factor;
        abs_sum += r.abs();
        sq_sum += r * r;
        y_min = y_min.min(o.radiance_factor);
        y_max = y_max.max(o.radiance_factor);
    }
    let flags = if lack_of_fit {
        vec![Flag::LackOfFit]
    } else {
        Vec::new()
    };
    Ok(FitResult {
        params,
        model,
        ci95,
        ci_clipped,
        covariance,
        budget,
        active_bounds,
        notes,
        acceptance_deg: problem.acceptance_deg,
        arm_offset,
        arm_offset_statistic,
        n,
        cost,
        chi2,
        gof_p,
        structure,
        lack_of_fit,
        variance_scale,
        noise_from_residuals,
        residual_variance: s2 * variance_scale,
        dof,
        nmae: abs_sum / n as f64 / (y_max - y_min),
        rms: (sq_sum / n as f64).sqrt(),
        iterations: outcome.iterations,
        status: outcome.status,
        weighted,
        flags,
    })
}

/// The normal equations of whitened columns X (p × n, each a column of the Jacobian
/// divided by the std) in the Σ⁻¹ metric: H = XᵀΣ⁻¹X, b = XᵀΣ⁻¹r (when `r` is given), and
/// P' = L⁻¹ S̃ᵀ X (m × p) for the shared terms' shares.
struct Normal {
    h: Square,
    b: Vec<f64>,
    pl: Vec<Vec<f64>>,
}

fn gls_normal(shared: &engine::Shared, columns: &[Vec<f64>], r: Option<&[f64]>) -> Normal {
    let p = columns.len();
    let m = shared.m;
    let n = columns.first().map_or(0, |c| c.len());
    let mut h = Square::zeros(p);
    let mut b = vec![0.0; p];
    for i in 0..p {
        for j in 0..=i {
            let s: f64 = columns[i].iter().zip(&columns[j]).map(|(a, c)| a * c).sum();
            *h.at_mut(i, j) = s;
            *h.at_mut(j, i) = s;
        }
        if let Some(r) = r {
            b[i] = columns[i].iter().zip(r).map(|(a, c)| a * c).sum();
        }
    }
    let mut pl = vec![vec![0.0; p]; m];
    if m > 0 {
        let mut q = vec![0.0; m];
        for row in 0..n {
            let s = shared.row(row);
            for k in 0..m {
                for (c, column) in columns.iter().enumerate() {
                    pl[k][c] += s[k] * column[row];
                }
                if let Some(r) = r {
                    q[k] += s[k] * r[row];
                }
            }
        }
        for c in 0..p {
            let mut column: Vec<f64> = (0..m).map(|k| pl[k][c]).collect();
            linalg::forward_substitute(&shared.l, &mut column);
            for k in 0..m {
                pl[k][c] = column[k];
            }
        }
        linalg::forward_substitute(&shared.l, &mut q);
        for i in 0..p {
            for j in 0..p {
                *h.at_mut(i, j) -= (0..m).map(|k| pl[k][i] * pl[k][j]).sum::<f64>();
            }
            b[i] -= (0..m).map(|k| pl[k][i] * q[k]).sum::<f64>();
        }
    }
    Normal { h, b, pl }
}

/// Without uncertainties, the parameters' covariance is the heteroscedasticity-consistent
/// sandwich from this many degrees of freedom on (below, s²·(JᵀJ)⁻¹ with s² from the
/// residuals): real readings are not equally noisy (a 1 % relative noise makes the peak's
/// readings 50 times noisier than the diffuse ones), and intervals that assume they are
/// cover σ of a glossy paper in a third of fits instead of 95 %. With fewer readings the
/// sandwich's one-residual-per-reading estimate is too unstable to use.
const SANDWICH_MIN_DOF: usize = 20;

/// HC3 sandwich H⁻¹ (Σ_i x_i x_iᵀ r_i² / (1 − h_ii)²) H⁻¹, h_ii = x_iᵀ H⁻¹ x_i the
/// leverage (clamped to 0.99), for unweighted columns X and residuals r.
fn sandwich(h_inv: &Square, columns: &[Vec<f64>], residuals: &[f64]) -> Square {
    let p = columns.len();
    let mut meat = Square::zeros(p);
    let mut x = vec![0.0; p];
    for (i, &r) in residuals.iter().enumerate() {
        for (xa, c) in x.iter_mut().zip(columns) {
            *xa = c[i];
        }
        let leverage: f64 = (0..p)
            .map(|a| (0..p).map(|b| x[a] * h_inv.at(a, b) * x[b]).sum::<f64>())
            .sum();
        let w = r * r / (1.0 - leverage.clamp(0.0, 0.99)).powi(2);
        for a in 0..p {
            for b in 0..p {
                *meat.at_mut(a, b) += w * x[a] * x[b];
            }
        }
    }
    let mut out = Square::zeros(p);
    for a in 0..p {
        for b in 0..p {
            let mut sum = 0.0;
            for c in 0..p {
                for d in 0..p {
                    sum += h_inv.at(a, c) * meat.at(c, d) * h_inv.at(d, b);
                }
            }
            *out.at_mut(a, b) = sum;
        }
    }
    out
}

/// What the arm-offset test found.
struct ArmSearch {
    /// The likelihood-ratio statistic, or the score screen's when the search was skipped.
    statistic: f64,
    /// The shifted problem and its fit, when δ0 passed the test.
    accepted: Option<(Problem, LmOutcome)>,
}

/// The joint Gauss–Newton step in (free x, δ0) at `outcome` on `problem`, and the score
/// statistic of δ0 (the part of the predicted decrease of the cost due to δ0).
fn arm_offset_step(problem: &Problem, x: &[f64; 4]) -> Option<(Vec<usize>, Vec<f64>, f64, f64)> {
    let (lo, hi) = (lower_bounds(), upper_bounds());
    let (residuals, jacobian) = problem.rows(x);
    let free: Vec<usize> = (0..4).filter(|&i| x[i] > lo[i] && x[i] < hi[i]).collect();
    let mut columns: Vec<Vec<f64>> = free
        .iter()
        .map(|&i| jacobian.iter().map(|row| row[i]).collect())
        .collect();
    columns.push(problem.shift_column(x));
    let normal = gls_normal(&problem.shared, &columns, Some(&residuals));
    let p = columns.len();
    let h_inv = linalg::spd_inverse(&normal.h)?;
    let step: Vec<f64> = (0..p)
        .map(|i| -(0..p).map(|j| h_inv.at(i, j) * normal.b[j]).sum::<f64>())
        .collect();
    let predicted: f64 = -step.iter().zip(&normal.b).map(|(s, b)| s * b).sum::<f64>();
    // The same without δ0: what the other parameters alone would still gain (≈ 0 at the optimum).
    let mut reduced = Square::zeros(p - 1);
    for i in 0..p - 1 {
        for j in 0..p - 1 {
            *reduced.at_mut(i, j) = normal.h.at(i, j);
        }
    }
    let without = linalg::spd_inverse(&reduced).map_or(0.0, |inv| {
        (0..p - 1)
            .map(|i| {
                (0..p - 1)
                    .map(|j| normal.b[i] * inv.at(i, j) * normal.b[j])
                    .sum::<f64>()
            })
            .sum()
    });
    // δ0's standard error at unit noise: the step below which the search has converged.
    let se = h_inv.at(p - 1, p - 1).max(0.0).sqrt();
    Some((free, step, (predicted - without).max(0.0), se))
}

/// Test for an arm zero offset and fit it when the data call for it: the score statistic
/// at δ0 = 0 screens; then Gauss–Newton steps on the profile cost c(δ0) (each a rebuilt
/// problem and a warm Levenberg–Marquardt run), and the likelihood ratio (c(0) − c(δ̂0))/s²
/// against [`ARM_OFFSET_LR_CRITICAL`] (s² = 1 weighted; without uncertainties the Wald
/// statistic δ̂0²/Var(δ̂0) with the sandwich variance, or s² from the residuals below
/// [`SANDWICH_MIN_DOF`]).
fn arm_offset_search(
    observations: &[Observation],
    shared: &[SharedError],
    acceptance: Option<f64>,
    base: &Problem,
    outcome: &LmOutcome,
    fitted_count: usize,
    max_iterations: usize,
) -> ArmSearch {
    let n = observations.len();
    let weighted = base.weighted;
    let dof_with = n.saturating_sub(fitted_count + 1).max(1) as f64;
    let s2_without = if weighted {
        1.0
    } else {
        outcome.cost / dof_with
    };
    let Some((free, step, score, se)) = arm_offset_step(base, &outcome.x) else {
        return ArmSearch {
            statistic: 0.0,
            accepted: None,
        };
    };
    let score = score / s2_without.max(1e-300);
    // Converged when the next step is a twentieth of δ0's standard error: the cost is then
    // within 0.0025 (in noise-variance units) of its minimum, far below any level tested.
    let tolerance = 0.05 * se * s2_without.sqrt();
    if score.is_nan() || score < ARM_OFFSET_SCREEN {
        return ArmSearch {
            statistic: score,
            accepted: None,
        };
    }
    let (lo, hi) = (lower_bounds(), upper_bounds());
    let mut best: Option<(Problem, LmOutcome)> = None;
    let mut delta = 0.0;
    let mut current_cost = outcome.cost;
    let mut current_x = outcome.x;
    let mut next = (free, step);
    for _ in 0..12 {
        let (free, step) = &next;
        let mut d_delta = step[step.len() - 1].clamp(-0.5, 0.5);
        let mut improved = false;
        for _ in 0..6 {
            let trial = (delta + d_delta).clamp(-ARM_OFFSET_MAX_DEG, ARM_OFFSET_MAX_DEG);
            let shifted = Problem::new(observations, shared, acceptance, trial);
            let fraction = if step[step.len() - 1] != 0.0 {
                d_delta / step[step.len() - 1]
            } else {
                0.0
            };
            let mut x0 = current_x;
            for (c, &i) in free.iter().enumerate() {
                x0[i] = (x0[i] + fraction * step[c]).clamp(lo[i], hi[i]);
            }
            let run = levenberg_marquardt(&shifted, x0, [false; 4], max_iterations);
            if run.cost < current_cost {
                delta = trial;
                current_cost = run.cost;
                current_x = run.x;
                best = Some((shifted, run));
                improved = true;
                break;
            }
            d_delta *= 0.5;
        }
        if !improved || d_delta.abs() < tolerance {
            break;
        }
        let Some((problem, _)) = &best else { break };
        match arm_offset_step(problem, &current_x) {
            Some((f, s, _, _)) if s[s.len() - 1].abs() >= tolerance => next = (f, s),
            _ => break,
        }
    }
    let Some((problem, run)) = best else {
        return ArmSearch {
            statistic: score,
            accepted: None,
        };
    };
    let s2 = if weighted { 1.0 } else { run.cost / dof_with };
    let mut lr = (outcome.cost - run.cost) / s2.max(1e-300);
    if !weighted && dof_with >= SANDWICH_MIN_DOF as f64 {
        // Without uncertainties the likelihood ratio assumes equal noise, which real
        // readings do not have (the peak's are far noisier): use the Wald statistic of δ0
        // with its heteroscedasticity-consistent variance instead, the sandwich the
        // intervals use.
        lr = robust_arm_offset_statistic(&problem, &run.x).unwrap_or(lr);
    }
    if lr > ARM_OFFSET_LR_CRITICAL {
        ArmSearch {
            statistic: lr,
            accepted: Some((problem, run)),
        }
    } else {
        ArmSearch {
            statistic: lr,
            accepted: None,
        }
    }
}

/// δ0² / Var_HC3(δ0) at the fit `x` of the shifted `problem` (unweighted).
fn robust_arm_offset_statistic(problem: &Problem, x: &[f64; 4]) -> Option<f64> {
    let (lo, hi) = (lower_bounds(), upper_bounds());
    let (residuals, jacobian) = problem.rows(x);
    let free: Vec<usize> = (0..4).filter(|&i| x[i] > lo[i] && x[i] < hi[i]).collect();
    let mut columns: Vec<Vec<f64>> = free
        .iter()
        .map(|&i| jacobian.iter().map(|row| row[i]).collect())
        .collect();
    columns.push(problem.shift_column(x));
    let normal = gls_normal(&problem.shared, &columns, None);
    let h_inv = linalg::spd_inverse(&normal.h)?;
    let cov = sandwich(&h_inv, &columns, &residuals);
    let p = columns.len();
    let variance = cov.at(p - 1, p - 1);
    (variance > 0.0).then(|| problem.shift_deg * problem.shift_deg / variance)
}

/// Largest σ whose profile cost (others refitted) stays within `threshold`, and the
/// parameters there: doubling, then bisection in ln σ to about 2 %.
fn sigma_upper_deg(
    problem: &Problem,
    best: &LmOutcome,
    threshold: f64,
    max_iterations: usize,
) -> (f64, [f64; 4]) {
    let profile = |ln_sigma: f64, start: [f64; 4]| {
        let mut x = start;
        x[0] = ln_sigma;
        levenberg_marquardt(problem, x, [true, false, false, false], max_iterations)
    };
    let mut inside = best.x[0];
    let mut start = best.x;
    let mut outside = None;
    let ln_max = SIGMA_MAX_DEG.ln();
    while inside < ln_max {
        let trial = (inside + std::f64::consts::LN_2).min(ln_max);
        let run = profile(trial, start);
        if run.cost > threshold {
            outside = Some(trial);
            break;
        }
        inside = trial;
        start = run.x;
    }
    let Some(mut outside) = outside else {
        return (SIGMA_MAX_DEG, start);
    };
    while outside - inside > 0.02 {
        let mid = 0.5 * (inside + outside);
        let run = profile(mid, start);
        if run.cost > threshold {
            outside = mid;
        } else {
            inside = mid;
            start = run.x;
        }
    }
    (inside.exp(), start)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::model::{self, PlaneGeometry};

    fn grid() -> Vec<Observation> {
        let mut out = Vec::new();
        for ti in [20.0, 30.0, 45.0, 60.0] {
            for k in 0..=140 {
                let tr = 0.5 * k as f64;
                out.push(Observation {
                    theta_i_deg: ti,
                    theta_r_deg: tr,
                    radiance_factor: 1.0 + tr * 1e-3,
                    std: Some(0.01),
                    theta_r_span_deg: 0.0,
                });
            }
        }
        out
    }

    /// The engine's tables give the public model's values and gradients, with and without
    /// the window, with and without an arm offset, at σ on both sides of the moments'
    /// two evaluation methods.
    #[test]
    fn engine_matches_the_model() {
        let obs = grid();
        for acceptance in [None, Some(1.0)] {
            for shift in [0.0, 0.3] {
                let problem = Problem::new(&obs, &[], acceptance, shift);
                for p in [
                    Params {
                        sigma_deg: 0.3,
                        rho_s: 40.0,
                        rho_d: 0.8,
                        eta: 1.19,
                    },
                    Params {
                        sigma_deg: 0.8,
                        rho_s: 57.8,
                        rho_d: 0.855,
                        eta: 1.19,
                    },
                    Params {
                        sigma_deg: 21.7,
                        rho_s: 0.409,
                        rho_d: 0.414,
                        eta: 2.5,
                    },
                ] {
                    let x = x_of(&p);
                    let values = problem.values(&x);
                    let (_, jac) = problem.rows(&x);
                    for (k, o) in obs.iter().enumerate() {
                        let (v, g) = model::evaluate(
                            &p,
                            &PlaneGeometry::new(o.theta_i_deg, o.theta_r_deg + shift),
                            acceptance,
                        );
                        assert!(
                            (values[k] - v).abs() <= 1e-12 * v.abs(),
                            "{acceptance:?} {shift} {p:?} {o:?}: {} vs {v}",
                            values[k]
                        );
                        // x = (ln σ, A, ρd, η): ∂/∂ln σ = σ ∂/∂σ, ∂/∂A = ∂/∂ρs / (η²−1).
                        let want_sigma = g[SIGMA] * p.sigma_deg / 0.01;
                        let want_a = g[RHO_S] / engine::eta_factor(p.eta) / 0.01;
                        assert!(
                            (jac[k][0] - want_sigma).abs() <= 1e-9 * (want_sigma.abs() + 1e-6),
                            "σ {o:?}: {} vs {want_sigma}",
                            jac[k][0]
                        );
                        assert!(
                            (jac[k][1] - want_a).abs() <= 1e-9 * (want_a.abs() + 1e-6),
                            "A {o:?}: {} vs {want_a}",
                            jac[k][1]
                        );
                    }
                    // The shift column against a difference of the engine's own values.
                    let column = problem.shift_column(&x);
                    let h = 1e-4;
                    let up = Problem::new(&obs, &[], acceptance, shift + h).values(&x);
                    let down = Problem::new(&obs, &[], acceptance, shift - h).values(&x);
                    for k in 0..obs.len() {
                        let fd = (up[k] - down[k]) / (2.0 * h) / 0.01;
                        assert!(
                            (column[k] - fd).abs() <= 1e-3 * (fd.abs() + 1.0),
                            "{acceptance:?} {p:?} reading {k}: {} vs {fd}",
                            column[k]
                        );
                    }
                }
            }
        }
    }

    /// Readings taken while the detector moved (a sweep's bins, mixed with still ones): the
    /// engine's tables give the public model's mean over the travel, its gradient, and
    /// the shift column, with and without the window.
    #[test]
    fn engine_matches_the_model_for_bins() {
        let obs: Vec<Observation> = grid()
            .into_iter()
            .step_by(3)
            .enumerate()
            .map(|(k, o)| Observation {
                theta_r_span_deg: [0.0, 0.06, 0.3, 1.5][k % 4],
                ..o
            })
            .collect();
        for acceptance in [None, Some(1.0)] {
            for shift in [0.0, 0.3] {
                let problem = Problem::new(&obs, &[], acceptance, shift);
                for p in [
                    Params {
                        sigma_deg: 0.8,
                        rho_s: 57.8,
                        rho_d: 0.855,
                        eta: 1.19,
                    },
                    Params {
                        sigma_deg: 21.7,
                        rho_s: 0.409,
                        rho_d: 0.414,
                        eta: 2.5,
                    },
                ] {
                    let x = x_of(&p);
                    let values = problem.values(&x);
                    let (_, jac) = problem.rows(&x);
                    for (k, o) in obs.iter().enumerate() {
                        let (v, g) = model::evaluate_reading(
                            &p,
                            o.theta_i_deg,
                            o.theta_r_deg + shift,
                            o.theta_r_span_deg,
                            acceptance,
                        );
                        assert!(
                            (values[k] - v).abs() <= 1e-12 * v.abs(),
                            "{acceptance:?} {shift} {p:?} {o:?}: {} vs {v}",
                            values[k]
                        );
                        let want_sigma = g[SIGMA] * p.sigma_deg / 0.01;
                        assert!(
                            (jac[k][0] - want_sigma).abs() <= 1e-9 * (want_sigma.abs() + 1e-6),
                            "σ {o:?}: {} vs {want_sigma}",
                            jac[k][0]
                        );
                    }
                    let column = problem.shift_column(&x);
                    let h = 1e-4;
                    let up = Problem::new(&obs, &[], acceptance, shift + h).values(&x);
                    let down = Problem::new(&obs, &[], acceptance, shift - h).values(&x);
                    for k in 0..obs.len() {
                        let fd = (up[k] - down[k]) / (2.0 * h) / 0.01;
                        assert!(
                            (column[k] - fd).abs() <= 1e-3 * (fd.abs() + 1.0),
                            "{acceptance:?} {p:?} reading {k}: {} vs {fd}",
                            column[k]
                        );
                    }
                }
            }
        }
    }

    /// Woodbury: the engine's cost with shared errors equals rᵀ Σ⁻¹ r with Σ formed and
    /// inverted densely.
    #[test]
    fn shared_errors_give_the_dense_gls_cost() {
        let obs: Vec<Observation> = grid().into_iter().step_by(12).collect();
        let n = obs.len();
        let shared: Vec<SharedError> = (0..3)
            .map(|k| SharedError {
                name: format!("term {k}"),
                sensitivity: (0..n).map(|i| 0.01 * ((i * (k + 2)) % 7) as f64).collect(),
                additive: Vec::new(),
            })
            .collect();
        let p = Params {
            sigma_deg: 5.0,
            rho_s: 0.5,
            rho_d: 0.9,
            eta: 1.5,
        };
        let problem = Problem::new(&obs, &shared, Some(1.0), 0.0);
        let cost = problem.accumulate(&x_of(&p), false).0;
        let mut sigma = Square::zeros(n);
        for i in 0..n {
            for j in 0..n {
                let shared_part: f64 = shared
                    .iter()
                    .map(|s| s.sensitivity[i] * s.sensitivity[j])
                    .sum();
                *sigma.at_mut(i, j) = shared_part + if i == j { 1e-4 } else { 0.0 };
            }
        }
        let inv = linalg::spd_inverse(&sigma).expect("positive definite");
        let values = problem.values(&x_of(&p));
        let r: Vec<f64> = values
            .iter()
            .zip(&obs)
            .map(|(f, o)| f - o.radiance_factor)
            .collect();
        let dense: f64 = (0..n)
            .map(|i| (0..n).map(|j| r[i] * inv.at(i, j) * r[j]).sum::<f64>())
            .sum();
        assert!((cost - dense).abs() <= 1e-9 * dense, "{cost} vs {dense}");
    }
}
