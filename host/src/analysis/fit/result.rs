//! What a fit returns: the parameters with their intervals and covariance, the budget,
//! the notes on what the data did not determine, and the goodness of fit.
use super::{ARM_OFFSET_LR_CRITICAL, ETA_MIN, N_PARAMS};
use crate::analysis::flags::Flag;
use crate::analysis::gof::StructureTest;
use crate::analysis::model::{PARAM_NAMES, Params, SIGMA};
use serde::Serialize;

/// One term of the uncertainty budget: its contribution to the variance of σ (deg²), ρs,
/// ρd and η. The terms add up to the diagonal of [`FitResult::covariance`].
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct BudgetTerm {
    /// `reading noise` (the independent part), a [`super::SharedError`]'s name, or `lack of fit`.
    pub name: String,
    /// Contribution to Var of σ (degrees), ρs, ρd, η (0 for what was not determined).
    pub variance: [f64; N_PARAMS],
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
        /// At the lower bound 1, where ρs = A/(η²−1) is unbounded above: ρs at η's 95 %
        /// upper limit (the profile's), the smallest ρs the data allow.
        #[serde(skip_serializing_if = "Option::is_none")]
        rho_s_lower: Option<f64>,
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
    /// The arm offset was fitted at ± [`super::ARM_OFFSET_MAX_DEG`], the most the fit looks for:
    /// the readings ask for more than a built instrument's zero can be off, so the offset
    /// stands for something else (a shape the model does not hold, or a broken arm).
    ArmOffsetAtLimit {
        /// δ0, degrees (at the limit).
        deg: f64,
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
    /// η moved beyond twice its standard error when the body was allowed to be
    /// non-Lambertian: it takes up the body's shape and is not trusted as the paper's
    /// refractive index; its interval covers both values.
    EtaAbsorbsBody {
        /// η with a Lambertian body.
        eta_lambert: f64,
        /// η with the non-Lambertian body.
        eta_body: f64,
    },
    /// η at its upper bound 3 and the data calling for more (the extension step's test,
    /// `extension::fresnel_flatter`): the sheet's Fresnel factor is flatter than any of the
    /// model's, so ρs (the lobe's amplitude over that factor) is the paper's only by the
    /// convention η = 3 and moves with η by orders of magnitude; the class may be wrong.
    /// Flagged `lack-of-fit` (the class confidence capped).
    FresnelFlatterThanModel {
        /// η where the fit with the bound lifted (to 30) left it.
        eta: f64,
        /// The likelihood-ratio statistic of η free against η = 3.
        lr: f64,
        /// Its critical value (the false-alarm rate 0.3 % on a sheet whose η is 3).
        critical: f64,
    },
    /// A reading so far from the fit that it is taken for a gross error (the outlier test,
    /// `outliers.rs`): named, left in the fit, flagged `outlier`.
    Outlier {
        /// Its position in the input (0-based).
        index: usize,
        /// Its line in the file it was read from (1-based), where the fit was given one.
        #[serde(skip_serializing_if = "Option::is_none")]
        line: Option<usize>,
        /// θi, degrees.
        theta_i_deg: f64,
        /// θr, degrees.
        theta_r_deg: f64,
        /// The reading's radiance factor.
        value: f64,
        /// The fit's value there.
        fitted: f64,
        /// (reading − fit) over the residual's standard deviation.
        standardized: f64,
        /// The test's critical value of |standardized| (Bonferroni over the readings).
        critical: f64,
        /// The test's false-alarm rate per data set.
        alpha: f64,
    },
    /// Too few readings beyond the fitted parameters to judge the fit or state a class
    /// confidence: flagged `few-degrees-of-freedom`.
    FewDegreesOfFreedom {
        /// ν, readings less fitted parameters.
        dof: usize,
        /// The smallest ν judged (3 without uncertainties, 1 with them).
        min_dof: usize,
    },
    /// ρd is beyond any paper's and reads as one once divided by 100: the radiance
    /// factors look like percent ([`crate::analysis::plausibility`]); flagged
    /// `implausible-input`.
    PercentSuspected {
        /// The fitted ρd.
        rho_d: f64,
        /// The largest radiance factor read.
        max_radiance_factor: f64,
    },
    /// Every angle within ±1.6: they look like radians; flagged `implausible-input`.
    RadiansSuspected {
        /// The largest |θi| or |θr| read, in the file's unit.
        max_abs_angle: f64,
    },
    /// The fitted paper is far from every paper of Table 6 (or ρd beyond a perfect
    /// diffuser): outside the population the classes were drawn from; flagged
    /// `implausible-input`.
    OutsidePopulation {
        /// The nearest paper of Table 6.
        nearest_reference: &'static str,
        /// Its distance, combined standard uncertainties.
        distance: f64,
        /// The fitted ρd.
        rho_d: f64,
    },
}

/// What η held at a bound means, and ρs's lower limit where it is 1.
fn eta_at_bound_text(eta: f64, rho_s_lower: Option<f64>) -> String {
    let held = format!("η at its bound {eta}: held there, not fitted");
    match rho_s_lower {
        Some(lower) => format!(
            "{held}; ρs = A/(η²−1) is unbounded above there, only ≥ {lower:.4} (its value at η's 95 % upper limit)"
        ),
        None => held,
    }
}

impl std::fmt::Display for Note {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Note::PercentSuspected {
                rho_d,
                max_radiance_factor,
            } => write!(
                f,
                "the radiance factors look like percent (×100): ρd = {rho_d:.3} and readings up to {max_radiance_factor:.4} where a paper's ρd is below 1 (a perfect diffuser is 1); radiance factors are fractions: divide the table by 100"
            ),
            Note::RadiansSuspected { max_abs_angle } => write!(
                f,
                "every angle is within ±{max_abs_angle:.3}: the angles look like radians; gonio reads θi and θr in degrees (multiply by 180/π)"
            ),
            Note::OutsidePopulation {
                nearest_reference,
                distance,
                rho_d,
            } => write!(
                f,
                "outside the population of papers: the nearest of Table 6's papers ({nearest_reference}) is {distance:.1} combined standard uncertainties away{}; a class would be an extrapolation and none is given; check the table's units and content",
                if *rho_d > crate::analysis::plausibility::RHO_D_MAX {
                    format!(" and ρd = {rho_d:.3} is beyond a perfect diffuser's 1")
                } else {
                    String::new()
                }
            ),
            Note::EtaAtBound { eta, rho_s_lower } => {
                f.write_str(&eta_at_bound_text(*eta, *rho_s_lower))
            }
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
            Note::NoiseFromResiduals { std } => write!(
                f,
                "no uncertainties given: the noise is estimated from the residuals (std {std:.3e} if equal for all readings; intervals allow it to differ between readings); no χ² test"
            ),
            Note::ArmOffsetFitted { deg, std_deg, lr } => write!(
                f,
                "arm zero offset fitted: every θr taken as θr + δ0, δ0 = {deg:+.3}° ± {std_deg:.3}° (test statistic {lr:.1} > {ARM_OFFSET_LR_CRITICAL:.2})"
            ),
            Note::ArmOffsetAtLimit { deg } => write!(
                f,
                "the arm zero offset sits at {deg:+.1}°, the limit of what the fit looks for: the readings ask for more than a built instrument's zero can be off, so the offset stands for something the model does not hold (a shape of the sheet, or a broken arm); σ, ρs, ρd rest on it; flagged lack-of-fit, class confidence capped"
            ),
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
            Note::FresnelFlatterThanModel { eta, lr, critical } => write!(
                f,
                "the data call for η beyond the model's bound 3 (free, η fits {eta:.2}; test {lr:.1} > {critical:.2}): the sheet's Fresnel factor is flatter than any the model allows, so ρs, the lobe's amplitude over that factor, is the paper's only by the convention η = 3 and may be off by orders of magnitude, and the class with it; flagged lack-of-fit, class confidence capped"
            ),
            Note::EtaAbsorbsBody {
                eta_lambert,
                eta_body,
            } => write!(
                f,
                "η is {eta_lambert:.3} with a Lambertian body and {eta_body:.3} with a non-Lambertian one: it takes up the body's shape, not trusted as a refractive index (its interval covers both)"
            ),
            Note::Outlier {
                index,
                line,
                theta_i_deg,
                theta_r_deg,
                value,
                fitted,
                standardized,
                critical,
                alpha,
            } => write!(
                f,
                "{} (θi {theta_i_deg}°, θr {theta_r_deg}°) is an outlier: {value} where the fit has {fitted:.4}, {standardized:+.1} standard deviations (critical ±{critical:.2} at {:.1} % false alarms per data set); check it, remove it if it is a gross error and fit again",
                line.map_or_else(
                    || format!("reading {} of the table", index + 1),
                    |l| format!("the reading on line {l}")
                ),
                100.0 * alpha
            ),
            Note::FewDegreesOfFreedom { dof, min_dof } => write!(
                f,
                "{dof} degrees of freedom (readings less fitted parameters), below the {min_dof} a fit is judged from: its goodness and noise cannot be tested, so no class confidence of 0.95 is stated; measure more geometries"
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
    pub(crate) std_deg: f64,
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
    pub(crate) ci_clipped: [bool; N_PARAMS],
    /// Covariance of (σ in degrees, ρs, ρd, η), arm offset marginalised, widened under lack of
    /// fit; rows and columns of parameters not fitted or not identified are 0.
    pub covariance: [[f64; N_PARAMS]; N_PARAMS],
    /// The covariance's diagonal by source; the terms add up to it.
    pub budget: Vec<BudgetTerm>,
    /// Parameters sitting on a bound.
    pub active_bounds: Vec<ActiveBound>,
    /// What the data did not determine, and how the result was reached.
    pub notes: Vec<Note>,
    /// The acceptance window modelled, degrees, if it was (a measured response: the
    /// top-hat width of its variance).
    pub acceptance_deg: Option<f64>,
    /// The arm zero offset, if the data called for one.
    pub arm_offset: Option<ArmOffset>,
    /// The statistic of the arm-offset test (likelihood ratio, or the score screen when the
    /// search was not needed); `None` when not tested.
    pub(crate) arm_offset_statistic: Option<f64>,
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
    pub(crate) residual_variance: f64,
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
    /// The fit's flags ([`Flag::LackOfFit`], [`Flag::ModelExtended`]).
    pub flags: Vec<Flag>,
    /// The extension step: the terms the data called for and every test made; `None`
    /// where it was not run (no resolved main lobe, too few readings, or switched off).
    pub extension: Option<super::Extension>,
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
    /// a window, η's interval reaching 1, or η held at 1 with its upper limit profiled).
    pub(crate) fn rho_s_lower(&self) -> Option<f64> {
        self.notes.iter().find_map(|n| match n {
            Note::SigmaUnresolved { rho_s_lower, .. } => *rho_s_lower,
            Note::RhoSUnbounded { rho_s_lower } => Some(*rho_s_lower),
            Note::EtaAtBound { rho_s_lower, .. } => *rho_s_lower,
            _ => None,
        })
    }

    /// Whether η is held at its lower bound 1, where only ρs·(η²−1) is determined.
    pub(crate) fn eta_at_floor(&self) -> bool {
        eta_at_floor_of(&self.notes)
    }

    /// Whether there is a specular part at all.
    pub(crate) fn has_specular_term(&self) -> bool {
        !self.notes.contains(&Note::NoSpecularTerm)
    }

    /// Standard uncertainty of a parameter (σ in degrees), if fitted and identified.
    pub fn std_error(&self, index: usize) -> Option<f64> {
        (self.model.0[index] && self.identified(index))
            .then(|| self.covariance[index][index].max(0.0).sqrt())
    }
}

/// A parameter the data do not identify carries no uncertainty anything downstream could
/// use: its row and column of the covariance and its share of every budget term are zeroed.
pub(super) fn forget_uncertainty(
    covariance: &mut [[f64; N_PARAMS]; N_PARAMS],
    budget: &mut [BudgetTerm],
    index: usize,
) {
    for k in 0..N_PARAMS {
        covariance[index][k] = 0.0;
        covariance[k][index] = 0.0;
    }
    for term in budget {
        term.variance[index] = 0.0;
    }
}

/// Whether the notes of a fit hold η at its lower bound 1.
pub(super) fn eta_at_floor_of(notes: &[Note]) -> bool {
    notes
        .iter()
        .any(|n| matches!(n, Note::EtaAtBound { eta, .. } if *eta <= ETA_MIN))
}

/// What the notes of a fit say was not identified.
pub(super) fn not_identified_of(notes: &[Note]) -> Vec<NotIdentified> {
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
            Note::EtaAtBound { eta, .. } if *eta <= ETA_MIN && !no_specular => {
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
