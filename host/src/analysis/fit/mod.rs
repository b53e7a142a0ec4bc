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
//! **The steps**, in the order [`fit_with_shared`] runs them, each in its own file:
//! 1. *validation* (`validation.rs`): the readings and the shared errors are checked
//!    before anything is computed on them, so a bad input is refused with its reading
//!    named instead of turning into an infinite cost or a NaN interval ([`FitError`],
//!    `error.rs`);
//! 2. *the global fit* (`engine.rs`): the shared errors' scaling parts evaluated at a
//!    first pass's model, then the seeding grid and Levenberg–Marquardt with them;
//! 3. *identifiability* (`identifiability.rs`): what the data cannot determine is taken
//!    out of the model and said so (no specular part; σ unresolved). It comes before the
//!    arm offset, which is only looked for where there is a resolved peak to shift;
//! 4. *the arm offset* (`arm_offset.rs`): an arm zero offset δ0 (θr → θr + δ0) is fitted
//!    when the data call for it (likelihood-ratio test at 1 %, [`ARM_OFFSET_LR_CRITICAL`]),
//!    else the zero's uncertainty is one more shared error; then η at a bound and the
//!    parameters on their bounds, which this step's refits may have moved;
//! 5. *covariance and widening* (`covariance.rs`): goodness of fit
//!    ([`crate::analysis::gof`]) on the final model, then the parameters' covariance
//!    C = G Σ Gᵀ (G the estimator's linearised map), split into the independent noise's
//!    and each shared error's share, widened when the model does not fit, and the
//!    intervals. It is last because every step before it may change the model it is of.
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
mod arm_offset;
mod covariance;
mod engine;
mod error;
mod extension;
mod identifiability;
mod outliers;
mod result;
mod validation;

use crate::analysis::flags::Flag;
use crate::analysis::model::{DetectorResponse, Params};
use engine::{LeastSquaresProblem, LmOutcome, global_fit, params_of, x_of};
use statrs::distribution::{ContinuousCDF, StudentsT};

pub use error::FitError;
pub use extension::{
    Extension, ExtensionTerm, MODEL_FORM, MemberSigma, ModelChoice, SHAPE_SENSITIVITY,
    SHAPES_OUTSIDE, ShiftFromPaperModel, Term, TermTest, on_by_default,
};
pub use outliers::OUTLIER_ALPHA_WEIGHTED;
pub use result::{
    ActiveBound, ArmOffset, Bound, BudgetTerm, FitResult, FittedModel, NotIdentified, Note, Status,
};
pub use validation::{validate, validate_shared};

/// Smallest σ the fit considers, degrees: far below what any sampling here resolves.
pub(crate) const SIGMA_MIN_DEG: f64 = 1e-3;
/// Upper bound of σ (Table 3), degrees.
pub(crate) const SIGMA_MAX_DEG: f64 = 90.0;
/// Lower bound of η (Table 3).
pub(crate) const ETA_MIN: f64 = 1.0;
/// Upper bound of η (Table 3).
pub(crate) const ETA_MAX: f64 = 3.0;
/// Parameters of the full model.
pub(crate) const N_PARAMS: usize = 4;
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
pub(crate) const ARM_OFFSET_MAX_DEG: f64 = 3.0;
/// δ0 is fitted when the likelihood-ratio statistic (cost without δ0 − cost with it, in
/// units of the noise variance) exceeds χ²(1) at 99 %.
pub(crate) const ARM_OFFSET_LR_CRITICAL: f64 = 6.634_896_601_021_213;
/// The widest detector travel a reading may have, degrees: a sweep's bin is a fraction of
/// a degree to a few degrees; beyond this it would average the specular peak away.
pub(crate) const MAX_SPAN_DEG: f64 = 20.0;

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
pub(crate) const ARM_ZERO: &str = "arm zero";

/// Standard uncertainty of the detector arm's zero that a session assumes unless told
/// otherwise, degrees: the zero is set at the home switch and by aligning the aperture, good
/// to about 8 microsteps of 0.0125°.
pub const DEFAULT_ARM_ZERO_UNCERTAINTY_DEG: f64 = 0.1;

/// Options of a fit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FitOptions {
    /// Full width of the detector's acceptance in θr, degrees (a top-hat, the declared
    /// window); `None` or 0 leaves it out. [`FitOptions::response`] replaces it when given.
    pub acceptance_deg: Option<f64>,
    /// The detector's measured angular response (an instrument profile's), used instead
    /// of the declared top-hat.
    pub response: Option<DetectorResponse>,
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
    /// it ([`crate::analysis::gof::chi2_upper_tail_scaled`]). 0: the stated noise is taken as exact.
    pub noise_scale_log_variance: f64,
    /// Test the nested extensions of the model (a heavy-tailed lobe, a haze lobe, σ
    /// varying with θi, a non-Lambertian body, a lobe wider on one side, …) and add those
    /// the data call for ([`extension`]'s module docs). By default as
    /// [`extension::on_by_default`] says.
    pub extensions: bool,
}

impl Default for FitOptions {
    /// Readings of unknown provenance: no arm zero error is assumed (a session states its
    /// instrument's, [`DEFAULT_ARM_ZERO_UNCERTAINTY_DEG`]).
    fn default() -> Self {
        FitOptions {
            acceptance_deg: Some(crate::analysis::model::DEFAULT_ACCEPTANCE_DEG),
            response: None,
            max_iterations: 200,
            arm_offset: true,
            arm_zero_uncertainty_deg: 0.0,
            noise_scale_log_variance: 0.0,
            extensions: extension::on_by_default(),
        }
    }
}

impl FitOptions {
    /// The detector window the fit models: the measured response if given, else the
    /// declared top-hat, else none (a point detector).
    pub fn window(&self) -> Option<DetectorResponse> {
        self.response
            .filter(|r| r.step_deg() > 0.0)
            .or_else(|| crate::analysis::model::top_hat_response(self.acceptance_deg))
    }
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
pub struct LinearProfile(LeastSquaresProblem);

impl LinearProfile {
    /// Validate and prepare the readings.
    pub fn new(
        observations: &[Observation],
        acceptance_deg: Option<f64>,
    ) -> Result<LinearProfile, FitError> {
        validate(observations)?;
        Ok(LinearProfile(LeastSquaresProblem::new(
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
    let problem = LeastSquaresProblem::new(observations, &[], acceptance_deg, 0.0);
    problem.accumulate(&x_of(params), false).0
}

/// Student t quantile at 0.975 for `dof` degrees of freedom (statrs); ∞ without any.
pub(crate) fn t_quantile_975(dof: usize) -> f64 {
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
    // 1. The data, refused with the first problem named.
    validate(observations)?;
    validate_shared(observations, shared)?;
    let acceptance = options.window();

    // 2. The shared errors at a first pass's model, then the global fit with them.
    let mut state = State::global(observations, shared, acceptance, options.max_iterations);

    // 3. What the data cannot determine: a specular part at all, a resolved peak.
    let unresolved = identifiability::specular_part(&mut state, acceptance, options);

    // 4. The arm zero: an offset where the data call for one, else its uncertainty as a
    //    shared error; then what the refits left at a bound.
    let arm = arm_offset::test_and_fit(
        &mut state,
        observations,
        shared,
        acceptance,
        unresolved,
        options,
    );
    if !arm.fitted && !unresolved {
        arm_offset::zero_uncertainty(&mut state, observations, acceptance, options);
    }
    identifiability::eta_at_bound(&mut state);
    let x = state.outcome.x;
    let cost = state.problem.accumulate(&x, false).0;
    let (active_bounds, free) = identifiability::active_bounds(&state);
    let model = FittedModel(state.fitted);
    let dof = observations
        .len()
        .saturating_sub(model.count() + usize::from(arm.fitted));

    // 5. Goodness of fit, the widening it calls for, and the parameters' covariance.
    let goodness = covariance::goodness_of_fit(&mut state, observations, &x, cost, dof, options);
    identifiability::rho_s_lower_at_eta_floor(
        &mut state,
        goodness.s2 * goodness.variance_scale,
        options.max_iterations,
    );
    let uncertainty = covariance::parameters(&mut state, &goodness, free, &arm, dof);
    // Gross errors among the readings, too few degrees of freedom (outliers.rs).
    let screen = outliers::screen(
        &state.problem,
        observations,
        &x,
        free,
        arm.fitted,
        dof,
        options.max_iterations,
    );
    let (shared_at_model, fitted) = (state.shared.clone(), state.fitted);
    let mut result = summary(
        observations,
        state,
        model,
        cost,
        active_bounds,
        &arm,
        goodness,
        uncertainty,
        dof,
    );
    outliers::record(&mut result, &screen, observations);

    // 6. The model grows where the data call for it; the intervals cover what they leave open.
    extension::extend(
        &extension::Base {
            observations,
            shared: &shared_at_model,
            response: acceptance,
            fitted,
            options,
        },
        &mut result,
    );
    // 7. An offset at the limit of its range is not an arm zero: the fit is not clean.
    arm_offset::flag_at_limit(&mut result);
    Ok(result)
}

/// The fit as its steps hand it on: the problem (the readings with the shared errors and the
/// arm offset in use), the best run on it, which parameters are fitted, and the notes so far.
struct State {
    problem: LeastSquaresProblem,
    outcome: LmOutcome,
    /// The shared errors as the problem holds them (at the model, the arm zero's added).
    shared: Vec<SharedError>,
    fitted: [bool; N_PARAMS],
    notes: Vec<Note>,
}

impl State {
    /// The global fit on the readings with their shared errors, whose scaling parts are
    /// first evaluated at the model of a pass without them re-evaluated ([`at_model`]).
    fn global(
        observations: &[Observation],
        given: &[SharedError],
        acceptance: Option<DetectorResponse>,
        max_iterations: usize,
    ) -> State {
        let shared: Vec<SharedError> = if given.is_empty() {
            Vec::new()
        } else {
            let first = LeastSquaresProblem::new(
                observations,
                &at_model(given, observations, None),
                acceptance,
                0.0,
            );
            let values = first.values(&global_fit(&first, max_iterations).x);
            at_model(given, observations, Some(&values))
        };
        let problem = LeastSquaresProblem::new(observations, &shared, acceptance, 0.0);
        let outcome = global_fit(&problem, max_iterations);
        State {
            problem,
            outcome,
            shared,
            fitted: [true; N_PARAMS],
            notes: Vec::new(),
        }
    }
}

/// The result from the steps' findings, with the residuals' summaries (NMAE, RMS).
#[allow(clippy::too_many_arguments)]
fn summary(
    observations: &[Observation],
    state: State,
    model: FittedModel,
    cost: f64,
    active_bounds: Vec<ActiveBound>,
    arm: &arm_offset::ArmTest,
    goodness: covariance::Goodness,
    uncertainty: covariance::Uncertainty,
    dof: usize,
) -> FitResult {
    let n = observations.len();
    let x = state.outcome.x;
    let values = state.problem.values(&x);
    let (mut abs_sum, mut sq_sum) = (0.0, 0.0);
    let (mut y_min, mut y_max) = (f64::INFINITY, f64::NEG_INFINITY);
    for (f, o) in values.iter().zip(observations) {
        let r = f - o.radiance_factor;
        abs_sum += r.abs();
        sq_sum += r * r;
        y_min = y_min.min(o.radiance_factor);
        y_max = y_max.max(o.radiance_factor);
    }
    let flags = if goodness.lack_of_fit {
        vec![Flag::LackOfFit]
    } else {
        Vec::new()
    };
    FitResult {
        params: params_of(&x),
        model,
        ci95: uncertainty.ci95,
        ci_clipped: uncertainty.ci_clipped,
        covariance: uncertainty.covariance,
        budget: uncertainty.budget,
        active_bounds,
        notes: state.notes,
        acceptance_deg: state.problem.response.map(|r| r.width_deg()),
        arm_offset: uncertainty.arm_offset,
        arm_offset_statistic: arm.statistic,
        n,
        cost,
        chi2: goodness.chi2,
        gof_p: goodness.gof_p,
        structure: goodness.structure,
        lack_of_fit: goodness.lack_of_fit,
        variance_scale: goodness.variance_scale,
        noise_from_residuals: goodness.noise_from_residuals,
        residual_variance: goodness.s2 * goodness.variance_scale,
        dof,
        nmae: abs_sum / n as f64 / (y_max - y_min),
        rms: (sq_sum / n as f64).sqrt(),
        iterations: state.outcome.iterations,
        status: state.outcome.status,
        weighted: state.problem.weighted,
        flags,
        extension: None,
    }
}
