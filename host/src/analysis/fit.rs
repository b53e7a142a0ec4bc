//! Least-squares fit of the TSL model (METHOD.md "Fitting") with the bounds of Table 3.
//!
//! How: ρs and ρd enter linearly, so for any (σ, η) their best non-negative values follow in
//! closed form (variable projection). A grid over log σ × η with that closed form gives the
//! profile of the cost and its basins, which is what makes the glossy papers' multimodal
//! problem safe; Levenberg–Marquardt on all four parameters (σ as ln σ, so σ > 0 holds by
//! construction; the others by an active-set projection) then polishes the best basins.
//! After the fit, what the data cannot determine is taken out of the model and said so.

use crate::analysis::model::{self, ETA, PARAM_NAMES, Params, PlaneGeometry, RHO_S, SIGMA};
use serde::Serialize;
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
/// χ²(1) at 95 %: a profile within this (× residual variance) of the minimum is consistent.
const CHI2_1_95: f64 = 3.841_458_820_694_124;
/// χ²(3) at 95 %.
const CHI2_3_95: f64 = 7.814_727_903_251_178;

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
}

/// Options of a fit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FitOptions {
    /// Full width of the detector's acceptance in θr, degrees; `None` or 0 leaves it out.
    pub acceptance_deg: Option<f64>,
    /// Levenberg–Marquardt iteration limit per start.
    pub max_iterations: usize,
}

impl Default for FitOptions {
    fn default() -> Self {
        FitOptions { acceptance_deg: Some(model::DEFAULT_ACCEPTANCE_DEG), max_iterations: 200 }
    }
}

/// Why a data set cannot be fitted. `index` is the reading's position in the input slice.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum FitError {
    /// Fewer distinct geometries than model parameters.
    #[error("only {found} distinct geometries: at least {needed} are needed to fit the {needed} parameters")]
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
    /// An angle outside 0…90°.
    #[error("reading {index}: {what} = {value}° is outside 0…90°")]
    AngleOutOfRange {
        /// Reading.
        index: usize,
        /// `theta_i` or `theta_r`.
        what: &'static str,
        /// The angle.
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
}

impl FitError {
    /// The reading the error is about, if it is about one.
    pub fn reading_index(&self) -> Option<usize> {
        match *self {
            FitError::NotFinite { index, .. }
            | FitError::Negative { index, .. }
            | FitError::AngleOutOfRange { index, .. }
            | FitError::BadUncertainty { index, .. }
            | FitError::MixedUncertainties { index }
            | FitError::ConflictingDuplicates { index, .. } => Some(index),
            FitError::TooFewGeometries { .. } | FitError::AllEqual { .. } => None,
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

/// Which side of its range a parameter sits on.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Bound {
    /// The lower bound.
    Lower,
    /// The upper bound.
    Upper,
}

/// What the data did not determine, and what was done about it.
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
    SigmaUnresolved {
        /// Largest σ the data allow (95 % profile), degrees.
        upper_deg: f64,
    },
    /// The normal matrix was singular at the optimum: no confidence intervals.
    SingularJacobian,
    /// As many parameters as geometries: no residual variance, no confidence intervals.
    NoDegreesOfFreedom,
}

impl std::fmt::Display for Note {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Note::EtaAtBound { eta } => write!(f, "η at its bound {eta}: held there, not fitted"),
            Note::NoSpecularTerm => f.write_str("no specular part: only ρd fitted (σ, η meaningless)"),
            Note::SigmaUnresolved { upper_deg } => {
                write!(f, "σ not resolved by the sampling: only known to be below {upper_deg:.3}°")
            }
            Note::SingularJacobian => f.write_str("singular normal matrix at the optimum: no confidence intervals"),
            Note::NoDegreesOfFreedom => f.write_str("as many parameters as geometries: no confidence intervals"),
        }
    }
}

/// Which parameters a fit estimated.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FittedModel(pub [bool; N_PARAMS]);

impl FittedModel {
    /// Names of the fitted parameters, in the order σ, ρs, ρd, η.
    pub fn names(&self) -> Vec<&'static str> {
        (0..N_PARAMS).filter(|&i| self.0[i]).map(|i| PARAM_NAMES[i]).collect()
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

/// The outcome of a fit.
#[derive(Clone, Debug, PartialEq)]
pub struct FitResult {
    /// Parameter values the fitted model uses (see [`FitResult::reported`] for which mean something).
    pub params: Params,
    /// Which parameters were estimated.
    pub model: FittedModel,
    /// 95 % confidence intervals (Student t on the Jacobian at the optimum), clipped to the
    /// bounds; `None` for parameters not fitted or when none can be given.
    pub ci95: [Option<(f64, f64)>; N_PARAMS],
    /// Whether each interval was clipped at a bound.
    pub ci_clipped: [bool; N_PARAMS],
    /// Covariance of (σ [deg], ρs, ρd, η); rows and columns of parameters not fitted are 0.
    pub covariance: [[f64; N_PARAMS]; N_PARAMS],
    /// Parameters sitting on a bound.
    pub active_bounds: Vec<ActiveBound>,
    /// What the data did not determine.
    pub notes: Vec<Note>,
    /// The acceptance window modelled, degrees, if it was.
    pub acceptance_deg: Option<f64>,
    /// Readings.
    pub n: usize,
    /// Weighted sum of squared residuals (the objective).
    pub cost: f64,
    /// Residual variance used for the intervals (1 when uncertainties were given).
    pub residual_variance: f64,
    /// Degrees of freedom, n − fitted parameters.
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
}

impl FitResult {
    /// A parameter's value if it means something: fitted, or held at a bound the data
    /// pushed it to. `None` for σ when unresolved and for σ, η without a specular part.
    pub fn reported(&self, index: usize) -> Option<f64> {
        let p = self.params.to_array();
        let no_specular = self.notes.contains(&Note::NoSpecularTerm);
        match index {
            SIGMA if no_specular || self.sigma_upper_deg().is_some() => None,
            ETA if no_specular => None,
            i if i < N_PARAMS => Some(p[i]),
            _ => None,
        }
    }

    /// σ in degrees if it was resolved.
    pub fn sigma_deg(&self) -> Option<f64> {
        self.reported(SIGMA)
    }

    /// Upper limit of σ when the sampling does not resolve the peak.
    pub fn sigma_upper_deg(&self) -> Option<f64> {
        self.notes.iter().find_map(|n| match n {
            Note::SigmaUnresolved { upper_deg } => Some(*upper_deg),
            _ => None,
        })
    }

    /// Whether there is a specular part at all.
    pub fn has_specular_term(&self) -> bool {
        !self.notes.contains(&Note::NoSpecularTerm)
    }

    /// Standard uncertainty of a parameter (σ in degrees), if fitted.
    pub fn std_error(&self, index: usize) -> Option<f64> {
        self.model.0[index].then(|| self.covariance[index][index].max(0.0).sqrt())
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

/// One reading prepared for the fit.
#[derive(Clone, Copy, Debug)]
struct Point {
    geometry: PlaneGeometry,
    y: f64,
    /// sqrt of the weight 1/std² (1 without uncertainties).
    sqrt_w: f64,
    /// Index of |θr − θi| in [`Problem::abs_offsets`].
    abs_offset: u32,
    /// Index of θr − θi in [`Problem::signed_offsets`].
    signed_offset: u32,
    /// Index of (sin² ψ, cos ψ) in [`Problem::psis`].
    psi: u32,
}

/// The fit's data with the distinct values of its geometry terms: a measurement grid
/// repeats lobe offsets and ψ many times (284 geometries have 61 distinct |θr − θi| and
/// 111 distinct ψ), so the exponentials and Fresnel terms are evaluated once per distinct
/// value and per pass. Each point's terms are bit-for-bit those of a direct evaluation.
struct Problem {
    points: Vec<Point>,
    acceptance_deg: Option<f64>,
    weighted: bool,
    /// Distinct |θr − θi|: the lobe without the window depends only on these.
    abs_offsets: Vec<f64>,
    /// Distinct θr − θi: the windowed lobe.
    signed_offsets: Vec<f64>,
    /// Distinct (sin² ψ, cos ψ).
    psis: Vec<(f64, f64)>,
    /// Per-pass tables, reused across passes: lobe (value, ∂σ) per offset, Fresnel
    /// (value, ∂η) per ψ.
    scratch: std::cell::RefCell<Scratch>,
}

#[derive(Default)]
struct Scratch {
    lobe: Vec<(f64, f64)>,
    fresnel: Vec<(f64, f64)>,
}

/// Distinct values of `keys` (by bits) and each key's index among them.
fn distinct<K: Copy + PartialEq, F: Fn(K) -> u128>(keys: &[K], bits: F) -> (Vec<K>, Vec<u32>) {
    let mut order: Vec<u32> = (0..keys.len() as u32).collect();
    order.sort_unstable_by_key(|&k| bits(keys[k as usize]));
    let mut values: Vec<K> = Vec::new();
    let mut index = vec![0u32; keys.len()];
    let mut last: Option<u128> = None;
    for k in order {
        let b = bits(keys[k as usize]);
        if last != Some(b) {
            values.push(keys[k as usize]);
            last = Some(b);
        }
        index[k as usize] = (values.len() - 1) as u32;
    }
    (values, index)
}

/// Check the input, naming the first problem.
pub fn validate(observations: &[Observation]) -> Result<(), FitError> {
    let weighted = observations.first().is_some_and(|o| o.std.is_some());
    for (index, o) in observations.iter().enumerate() {
        for (what, value) in [("theta_i", o.theta_i_deg), ("theta_r", o.theta_r_deg)] {
            if !value.is_finite() {
                return Err(FitError::NotFinite { index, what });
            }
            if !(0.0..=90.0).contains(&value) {
                return Err(FitError::AngleOutOfRange { index, what, value });
            }
        }
        if !o.radiance_factor.is_finite() {
            return Err(FitError::NotFinite { index, what: "radiance_factor" });
        }
        if o.radiance_factor < 0.0 {
            return Err(FitError::Negative { index, value: o.radiance_factor });
        }
        match o.std {
            Some(s) if !s.is_finite() => return Err(FitError::NotFinite { index, what: "std" }),
            Some(s) if s <= 0.0 => return Err(FitError::BadUncertainty { index, value: s }),
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
        oa.theta_i_deg.total_cmp(&ob.theta_i_deg).then(oa.theta_r_deg.total_cmp(&ob.theta_r_deg)).then(a.cmp(&b))
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
        return Err(FitError::TooFewGeometries { found: distinct, needed: N_PARAMS });
    }
    let (lo, hi) = observations
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), o| (lo.min(o.radiance_factor), hi.max(o.radiance_factor)));
    if lo == hi {
        return Err(FitError::AllEqual { n: observations.len(), value: lo });
    }
    Ok(())
}

impl Problem {
    fn new(observations: &[Observation], acceptance_deg: Option<f64>) -> Problem {
        let weighted = observations.first().is_some_and(|o| o.std.is_some());
        let geometries: Vec<PlaneGeometry> =
            observations.iter().map(|o| PlaneGeometry::new(o.theta_i_deg, o.theta_r_deg)).collect();
        let abs: Vec<f64> = geometries.iter().map(|g| g.offset_deg.abs()).collect();
        let signed: Vec<f64> = geometries.iter().map(|g| g.offset_deg).collect();
        let psi: Vec<(f64, f64)> = geometries.iter().map(|g| (g.sin2_psi, g.cos_psi)).collect();
        let (abs_offsets, abs_index) = distinct(&abs, |v| v.to_bits() as u128);
        let (signed_offsets, signed_index) = distinct(&signed, |v| v.to_bits() as u128);
        let (psis, psi_index) = distinct(&psi, |(a, b)| ((a.to_bits() as u128) << 64) | b.to_bits() as u128);
        let points = observations
            .iter()
            .zip(geometries)
            .enumerate()
            .map(|(k, (o, geometry))| Point {
                geometry,
                y: o.radiance_factor,
                sqrt_w: o.std.map_or(1.0, |s| 1.0 / s),
                abs_offset: abs_index[k],
                signed_offset: signed_index[k],
                psi: psi_index[k],
            })
            .collect();
        Problem {
            points,
            acceptance_deg: acceptance_deg.filter(|&a| a > 0.0),
            weighted,
            abs_offsets,
            signed_offsets,
            psis,
            scratch: Default::default(),
        }
    }

    /// The lobe's offset table in use (signed with the window, else |offset|) and a
    /// point's index into it.
    fn offsets(&self) -> &[f64] {
        if self.acceptance_deg.is_some() { &self.signed_offsets } else { &self.abs_offsets }
    }

    #[inline]
    fn offset_index(&self, pt: &Point) -> usize {
        if self.acceptance_deg.is_some() { pt.signed_offset as usize } else { pt.abs_offset as usize }
    }

    /// Fill `out` with the lobe (value, ∂σ) at σ for every distinct offset in use.
    fn lobe_table(&self, sigma_deg: f64, out: &mut Vec<(f64, f64)>) {
        out.clear();
        match self.acceptance_deg {
            Some(a) => out.extend(self.signed_offsets.iter().map(|&o| model::windowed_lobe_with_derivative(o, sigma_deg, a))),
            None => out.extend(self.abs_offsets.iter().map(|&o| model::lobe_with_derivative(o, sigma_deg))),
        }
    }

    /// Cost at x = [ln σ, A = ρs·(η²−1), ρd, η], with JᵀJ and Jᵀr in x when `jacobian`.
    fn accumulate(&self, x: &[f64; 4], jacobian: bool) -> (f64, [[f64; 4]; 4], [f64; 4]) {
        let sigma = x[0].exp();
        let (amplitude, rho_d, eta) = (x[1], x[2], x[3]);
        let mut cost = 0.0;
        let mut a = [[0.0; 4]; 4];
        let mut g = [0.0; 4];
        let mut scratch = self.scratch.borrow_mut();
        let Scratch { lobe, fresnel } = &mut *scratch;
        self.lobe_table(sigma, lobe);
        fresnel.clear();
        fresnel.extend(self.psis.iter().map(|&(s2, c)| model::reduced_fresnel_with_derivative(s2, c, eta)));
        for pt in &self.points {
            let (e, de) = lobe[self.offset_index(pt)];
            let (fr, dfr) = fresnel[pt.psi as usize];
            let h = pt.geometry.attenuation_over_cosines;
            let shape = fr * h * e;
            let f = amplitude * shape + rho_d;
            let r = pt.sqrt_w * (f - pt.y);
            cost += r * r;
            if jacobian {
                let j = [
                    pt.sqrt_w * amplitude * fr * h * de * sigma,
                    pt.sqrt_w * shape,
                    pt.sqrt_w,
                    pt.sqrt_w * amplitude * dfr * h * e,
                ];
                for row in 0..4 {
                    g[row] += j[row] * r;
                    for col in row..4 {
                        a[row][col] += j[row] * j[col];
                    }
                }
            }
        }
        for row in 0..4 {
            for col in 0..row {
                a[row][col] = a[col][row];
            }
        }
        (cost, a, g)
    }

    /// Best non-negative (ρs, ρd) at (σ, η).
    fn linear(&self, sigma_deg: f64, eta: f64) -> LinearSolution {
        let (mut sw, mut sy, mut syy, mut sg, mut sgg, mut sgy) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        let mut scratch = self.scratch.borrow_mut();
        let Scratch { lobe, fresnel } = &mut *scratch;
        self.lobe_table(sigma_deg, lobe);
        fresnel.clear();
        fresnel.extend(self.psis.iter().map(|&(s2, c)| model::fresnel_with_derivative(s2, c, eta)));
        for pt in &self.points {
            let w = pt.sqrt_w * pt.sqrt_w;
            let f = fresnel[pt.psi as usize].0;
            let g = f * pt.geometry.attenuation_over_cosines * lobe[self.offset_index(pt)].0;
            sw += w;
            sy += w * pt.y;
            syy += w * pt.y * pt.y;
            sg += w * g;
            sgg += w * g * g;
            sgy += w * g * pt.y;
        }
        solve_linear(sw, sy, syy, sg, sgg, sgy)
    }
}

/// (η² − 1), the factor between the fit's amplitude A and ρs.
fn eta_factor(eta: f64) -> f64 {
    (eta - 1.0) * (eta + 1.0)
}

fn params_of(x: &[f64; 4]) -> Params {
    Params { sigma_deg: x[0].exp(), rho_s: x[1] / eta_factor(x[3]), rho_d: x[2], eta: x[3] }
}

/// x = [ln σ, A, ρd, η] of parameters.
fn x_of(p: &Params) -> [f64; 4] {
    [p.sigma_deg.ln(), p.rho_s * eta_factor(p.eta), p.rho_d, p.eta]
}

/// η = 1 itself has F ≡ 0; the fit stops just above it, where ρs = A/(η²−1) is still
/// finite, and reports η at its bound with ρs undetermined.
const ETA_FLOOR: f64 = ETA_MIN + 1e-6;

fn lower_bounds() -> [f64; 4] {
    [SIGMA_MIN_DEG.ln(), 0.0, 0.0, ETA_FLOOR]
}

fn upper_bounds() -> [f64; 4] {
    [SIGMA_MAX_DEG.ln(), f64::INFINITY, f64::INFINITY, ETA_MAX]
}

/// Closed-form non-negative least squares for f = ρs·g + ρd from the weighted sums.
fn solve_linear(sw: f64, sy: f64, syy: f64, sg: f64, sgg: f64, sgy: f64) -> LinearSolution {
    let cost_of = |a: f64, b: f64| (syy - 2.0 * a * sgy - 2.0 * b * sy + a * a * sgg + 2.0 * a * b * sg + b * b * sw).max(0.0);
    let det = sw * sgg - sg * sg;
    if det > 1e-12 * sw * sgg {
        let rho_s = (sw * sgy - sg * sy) / det;
        let rho_d = (sgg * sy - sg * sgy) / det;
        if rho_s >= 0.0 && rho_d >= 0.0 {
            return LinearSolution { rho_s, rho_d, cost: cost_of(rho_s, rho_d) };
        }
    }
    // The unconstrained optimum is infeasible (or g has no shape): the best lies on an edge.
    let lambert = LinearSolution { rho_s: 0.0, rho_d: (sy / sw).max(0.0), cost: cost_of(0.0, (sy / sw).max(0.0)) };
    if sgg > 0.0 {
        let rho_s = (sgy / sgg).max(0.0);
        let specular_only = LinearSolution { rho_s, rho_d: 0.0, cost: cost_of(rho_s, 0.0) };
        if specular_only.cost < lambert.cost {
            return specular_only;
        }
    }
    lambert
}

/// The best non-negative ρs, ρd at a given (σ, η) and the cost there: the inner problem of
/// the fit, public so that a brute-force search can check the fit's global minimum.
pub fn linear_profile(
    observations: &[Observation],
    sigma_deg: f64,
    eta: f64,
    acceptance_deg: Option<f64>,
) -> Result<LinearSolution, FitError> {
    validate(observations)?;
    Ok(Problem::new(observations, acceptance_deg).linear(sigma_deg, eta))
}

/// Weighted cost of given parameters (the fit's objective).
pub fn cost(observations: &[Observation], params: &Params, acceptance_deg: Option<f64>) -> f64 {
    let problem = Problem::new(observations, acceptance_deg);
    problem.accumulate(&x_of(params), false).0
}

/// σ grid of the global search: log-spaced, 1.25 apart, from 0.05° (finer than any
/// sampling here resolves) to 90°.
fn sigma_grid() -> impl Iterator<Item = f64> {
    const RATIO: f64 = 1.25;
    let n = ((SIGMA_MAX_DEG / 0.05).ln() / RATIO.ln()).ceil() as i32;
    (0..=n).map(move |k| (0.05 * RATIO.powi(k)).min(SIGMA_MAX_DEG))
}

/// η grid of the global search: denser near 1, where F changes fastest relative to itself.
const ETA_GRID: [f64; 11] = [1.005, 1.01, 1.02, 1.04, 1.08, 1.19, 1.35, 1.6, 2.0, 2.5, 3.0];

/// Starting points from the grid: the best (η, ρs, ρd) at each σ, then the lowest local
/// minima of that profile in σ, best first.
fn seeds(problem: &Problem, max_seeds: usize) -> Vec<[f64; 4]> {
    let (mut sw, mut sy, mut syy) = (0.0, 0.0, 0.0);
    for pt in &problem.points {
        let w = pt.sqrt_w * pt.sqrt_w;
        sw += w;
        sy += w * pt.y;
        syy += w * pt.y * pt.y;
    }
    // Per η and distinct lobe offset o: the sums over the points at o of u = w·F·H, u·y
    // and u·F·H, so each (σ, η) costs three dot products over the distinct offsets (61
    // for the 284-geometry grid) and each σ one exponential per distinct offset.
    let m = problem.offsets().len();
    let mut fresnel = vec![0.0; problem.psis.len()];
    let mut u = vec![0.0; ETA_GRID.len() * m];
    let mut uy = vec![0.0; ETA_GRID.len() * m];
    let mut uu = vec![0.0; ETA_GRID.len() * m];
    for (e, &eta) in ETA_GRID.iter().enumerate() {
        for (f, &(s2, c)) in fresnel.iter_mut().zip(&problem.psis) {
            *f = model::fresnel_with_derivative(s2, c, eta).0;
        }
        for pt in &problem.points {
            let fh = fresnel[pt.psi as usize] * pt.geometry.attenuation_over_cosines;
            let w = pt.sqrt_w * pt.sqrt_w;
            let k = e * m + problem.offset_index(pt);
            u[k] += w * fh;
            uy[k] += w * fh * pt.y;
            uu[k] += w * fh * fh;
        }
    }
    let mut table = Vec::with_capacity(m);
    let mut lobe = vec![0.0; m];
    let mut profile: Vec<(f64, [f64; 4])> = Vec::with_capacity(40);
    let mut eta_costs: Vec<f64> = Vec::with_capacity(40 * ETA_GRID.len());
    for sigma in sigma_grid() {
        problem.lobe_table(sigma, &mut table);
        for (l, &(v, _)) in lobe.iter_mut().zip(&table) {
            *l = v;
        }
        let mut best = (f64::INFINITY, [0.0; 4]);
        for (e, &eta) in ETA_GRID.iter().enumerate() {
            let range = e * m..(e + 1) * m;
            // Four partial sums per dot product: independent chains the compiler can
            // keep in vector registers.
            let (mut sg4, mut sgy4, mut sgg4) = ([0.0; 4], [0.0; 4], [0.0; 4]);
            let (l, u, uy, uu) = (&lobe[..], &u[range.clone()], &uy[range.clone()], &uu[range]);
            let whole = m / 4 * 4;
            for c in (0..whole).step_by(4) {
                for j in 0..4 {
                    let lj = l[c + j];
                    sg4[j] += u[c + j] * lj;
                    sgy4[j] += uy[c + j] * lj;
                    sgg4[j] += uu[c + j] * lj * lj;
                }
            }
            for k in whole..m {
                sg4[0] += u[k] * l[k];
                sgy4[0] += uy[k] * l[k];
                sgg4[0] += uu[k] * l[k] * l[k];
            }
            let sum4 = |v: [f64; 4]| (v[0] + v[1]) + (v[2] + v[3]);
            let (sg, sgy, sgg) = (sum4(sg4), sum4(sgy4), sum4(sgg4));
            let s = solve_linear(sw, sy, syy, sg, sgg, sgy);
            eta_costs.push(s.cost);
            if s.cost < best.0 {
                best = (s.cost, [sigma.ln(), s.rho_s * eta_factor(eta), s.rho_d, eta]);
            }
        }
        profile.push(best);
    }
    let minima: Vec<(f64, [f64; 4])> = (0..profile.len())
        .filter(|&i| {
            let c = profile[i].0;
            (i == 0 || c <= profile[i - 1].0) && (i + 1 == profile.len() || c <= profile[i + 1].0)
        })
        .map(|i| profile[i])
        .collect();
    let n_eta = ETA_GRID.len();
    let mut minima: Vec<(f64, [f64; 4])> = minima
        .into_iter()
        .map(|(c, x)| {
            // Polish the grid point by parabolas through its neighbours, in ln σ along the
            // profile and in η along its row: starting in the right place of the narrow
            // ρs–η valley of nearly-Fresnel-free papers (η → 1) saves most LM iterations.
            let i = profile.iter().position(|p| p.1 == x).unwrap_or(0);
            let ln_sigma = if i > 0 && i + 1 < profile.len() {
                parabola_min([profile[i - 1].1[0], x[0], profile[i + 1].1[0]], [profile[i - 1].0, c, profile[i + 1].0]).unwrap_or(x[0])
            } else {
                x[0]
            };
            let row = &eta_costs[i * n_eta..(i + 1) * n_eta];
            let e = ETA_GRID.iter().position(|&eta| eta == x[3]).unwrap_or(0);
            let eta = if e > 0 && e + 1 < n_eta {
                parabola_min([ETA_GRID[e - 1], ETA_GRID[e], ETA_GRID[e + 1]], [row[e - 1], row[e], row[e + 1]]).unwrap_or(x[3])
            } else {
                x[3]
            };
            let refined = problem.linear(ln_sigma.exp(), eta);
            if refined.cost < c { (refined.cost, [ln_sigma, refined.rho_s * eta_factor(eta), refined.rho_d, eta]) } else { (c, x) }
        })
        .collect();
    minima.sort_by(|a, b| a.0.total_cmp(&b.0));
    // Basins far worse than the best on the grid do not compete after polishing either.
    let best_cost = minima.first().map_or(0.0, |m| m.0);
    minima.retain(|m| m.0 <= 2.0 * best_cost + 1e-300);
    minima.truncate(max_seeds);
    minima.into_iter().map(|(_, x)| x).collect()
}

/// Abscissa of the minimum of the parabola through three points, if it opens upwards and
/// the minimum lies between the outer points.
fn parabola_min(x: [f64; 3], y: [f64; 3]) -> Option<f64> {
    let d1 = (y[1] - y[0]) / (x[1] - x[0]);
    let d2 = (y[2] - y[1]) / (x[2] - x[1]);
    let curvature = (d2 - d1) / (x[2] - x[0]);
    if !(curvature > 0.0) {
        return None;
    }
    let m = 0.5 * (x[0] + x[1]) - d1 / (2.0 * curvature);
    (m > x[0] && m < x[2]).then_some(m)
}

struct LmOutcome {
    x: [f64; 4],
    cost: f64,
    iterations: usize,
    status: Status,
}

/// Solve the symmetric positive definite system m·x = b on the indices in `free`
/// (others get 0) by Cholesky; `None` if not positive definite.
fn solve_spd(m: &[[f64; 4]; 4], b: &[f64; 4], free: &[bool; 4]) -> Option<[f64; 4]> {
    let idx: Vec<usize> = (0..4).filter(|&i| free[i]).collect();
    let k = idx.len();
    let mut l = [[0.0; 4]; 4];
    for i in 0..k {
        for j in 0..=i {
            let mut s = m[idx[i]][idx[j]];
            for p in 0..j {
                s -= l[i][p] * l[j][p];
            }
            if i == j {
                if !(s > 0.0) || !s.is_finite() {
                    return None;
                }
                l[i][i] = s.sqrt();
            } else {
                l[i][j] = s / l[j][j];
            }
        }
    }
    let mut y = [0.0; 4];
    for i in 0..k {
        let mut s = b[idx[i]];
        for p in 0..i {
            s -= l[i][p] * y[p];
        }
        y[i] = s / l[i][i];
    }
    let mut x = [0.0; 4];
    for i in (0..k).rev() {
        let mut s = y[i];
        for p in i + 1..k {
            s -= l[p][i] * x[p];
        }
        x[i] = s / l[i][i];
    }
    let mut out = [0.0; 4];
    for i in 0..k {
        out[idx[i]] = x[i];
    }
    Some(out)
}

/// Inverse of the sub-matrix on `free` (zeros elsewhere), `None` if singular.
pub(crate) fn inverse_spd(m: &[[f64; 4]; 4], free: &[bool; 4]) -> Option<[[f64; 4]; 4]> {
    // Scale to unit diagonal first so that parameters of very different size do not
    // make a well-posed matrix look singular.
    let d: [f64; 4] = std::array::from_fn(|i| if free[i] && m[i][i] > 0.0 { 1.0 / m[i][i].sqrt() } else { 0.0 });
    if (0..4).any(|i| free[i] && d[i] == 0.0) {
        return None;
    }
    let scaled: [[f64; 4]; 4] = std::array::from_fn(|i| std::array::from_fn(|j| m[i][j] * d[i] * d[j]));
    let mut inv = [[0.0; 4]; 4];
    for c in 0..4 {
        if !free[c] {
            continue;
        }
        let mut e = [0.0; 4];
        e[c] = 1.0;
        let col = solve_spd(&scaled, &e, free)?;
        for r in 0..4 {
            inv[r][c] = col[r] * d[r] * d[c];
        }
    }
    // A near-singular matrix shows as a huge scaled inverse.
    if (0..4).any(|i| free[i] && !(inv[i][i] * m[i][i] < 1e12)) {
        return None;
    }
    Some(inv)
}

/// Levenberg–Marquardt with Marquardt's diagonal scaling and bounds by an active set:
/// a parameter on a bound whose gradient points out of the box is held for that step.
fn levenberg_marquardt(problem: &Problem, x0: [f64; 4], fixed: [bool; 4], max_iterations: usize) -> LmOutcome {
    levenberg_marquardt_until(problem, x0, fixed, max_iterations, 0.0)
}

/// [`levenberg_marquardt`] that also stops as soon as the cost is at or below `good_enough`.
fn levenberg_marquardt_until(
    problem: &Problem,
    x0: [f64; 4],
    fixed: [bool; 4],
    max_iterations: usize,
    good_enough: f64,
) -> LmOutcome {
    let (lo, hi) = (lower_bounds(), upper_bounds());
    let mut x: [f64; 4] = std::array::from_fn(|i| x0[i].clamp(lo[i], hi[i]));
    let (mut cost, mut a, mut g) = problem.accumulate(&x, true);
    let mut lambda = 1e-3;
    for iteration in 1..=max_iterations {
        let free: [bool; 4] =
            std::array::from_fn(|i| !fixed[i] && !((x[i] <= lo[i] && g[i] > 0.0) || (x[i] >= hi[i] && g[i] < 0.0)));
        if !free.iter().any(|&f| f) || cost <= good_enough {
            return LmOutcome { x, cost, iterations: iteration - 1, status: Status::Converged };
        }
        let trace: f64 = (0..4).filter(|&i| free[i]).map(|i| a[i][i]).sum();
        let floor = 1e-12 * trace.max(f64::MIN_POSITIVE);
        loop {
            let mut m = a;
            for i in 0..4 {
                m[i][i] += lambda * a[i][i].max(floor);
            }
            let neg_g = [-g[0], -g[1], -g[2], -g[3]];
            let step = solve_spd(&m, &neg_g, &free);
            if let Some(step) = step {
                let x_new: [f64; 4] = std::array::from_fn(|i| (x[i] + step[i]).clamp(lo[i], hi[i]));
                let (cost_new, a_new, g_new) = problem.accumulate(&x_new, true);
                if cost_new.is_finite() && cost_new < cost {
                    let small_step = (0..4).all(|i| (x_new[i] - x[i]).abs() <= 1e-10 * (x[i].abs() + 1e-8));
                    let small_decrease = cost - cost_new <= 1e-12 * cost;
                    x = x_new;
                    cost = cost_new;
                    a = a_new;
                    g = g_new;
                    lambda = (lambda * 0.1).max(1e-12);
                    if small_step || small_decrease {
                        return LmOutcome { x, cost, iterations: iteration, status: Status::Converged };
                    }
                    break;
                }
            }
            lambda *= 10.0;
            if lambda > 1e14 {
                // No downhill step however short: a (possibly bounded) minimum.
                return LmOutcome { x, cost, iterations: iteration, status: Status::Converged };
            }
        }
    }
    LmOutcome { x, cost, iterations: max_iterations, status: Status::IterationLimit }
}

/// Global search then local polish, on the full model.
fn global_fit(problem: &Problem, max_iterations: usize) -> LmOutcome {
    let mut best: Option<LmOutcome> = None;
    for seed in seeds(problem, 3) {
        let run = levenberg_marquardt(problem, seed, [false; 4], max_iterations);
        if best.as_ref().is_none_or(|b| run.cost < b.cost) {
            best = Some(run);
        }
    }
    // seeds() always returns at least one point (the grid is not empty).
    best.unwrap_or_else(|| levenberg_marquardt(problem, [0.0, 1.0, 0.5, 1.5], [false; 4], max_iterations))
}

/// Student t quantile at 0.975 for `dof` degrees of freedom (exact for 1 and 2, else the
/// Cornish–Fisher series, Abramowitz & Stegun 26.7.5, better than 1e-3 from 3 on).
pub fn t_quantile_975(dof: usize) -> f64 {
    const Z: f64 = 1.959_963_984_540_054;
    match dof {
        0 => f64::INFINITY,
        1 => 12.706_204_736_174_7,
        2 => 4.302_652_729_749_464,
        _ => {
            let v = dof as f64;
            let z2 = Z * Z;
            let g1 = (z2 + 1.0) * Z / 4.0;
            let g2 = ((5.0 * z2 + 16.0) * z2 + 3.0) * Z / 96.0;
            let g3 = (((3.0 * z2 + 19.0) * z2 + 17.0) * z2 - 15.0) * Z / 384.0;
            let g4 = ((((79.0 * z2 + 776.0) * z2 + 1482.0) * z2 - 1920.0) * z2 - 945.0) * Z / 92160.0;
            Z + g1 / v + g2 / (v * v) + g3 / (v * v * v) + g4 / (v * v * v * v)
        }
    }
}

/// Fit the TSL model to the readings.
pub fn fit(observations: &[Observation], options: &FitOptions) -> Result<FitResult, FitError> {
    validate(observations)?;
    let mut problem = Problem::new(observations, None);
    let n = observations.len();
    let mut outcome = global_fit(&problem, options.max_iterations);
    let mut notes = Vec::new();
    let mut fitted = [true; 4];
    let lo = lower_bounds();
    let hi = upper_bounds();
    let at_lower = |x: &[f64; 4], i: usize| x[i] <= lo[i];

    let residual_variance = |cost: f64, p: usize| {
        if problem_weighted(observations) { 1.0 } else { cost / (n.saturating_sub(p).max(1)) as f64 }
    };

    // Is there a specular part at all? A lobe that improves on a constant by less than
    // χ²(3) at 95 % (× residual variance) is noise being fitted: the three extra
    // parameters are not supported.
    let lambert_cost = {
        let rho_d = lambert_fit(&problem);
        problem.accumulate(&[0.0, 0.0, rho_d, ETA_MAX], false).0
    };
    let no_lobe = (lambert_cost - outcome.cost) <= CHI2_3_95 * residual_variance(outcome.cost, 4);
    if no_lobe || at_lower(&outcome.x, RHO_S) {
        // F ≡ 0 or ρs = 0: the specular part is absent and only ρd remains.
        notes.push(Note::NoSpecularTerm);
        fitted = [false, false, true, false];
        let lambert = lambert_fit(&problem);
        outcome = LmOutcome { x: [outcome.x[0], 0.0, lambert, ETA_MAX], cost: 0.0, ..outcome };
        outcome.cost = problem.accumulate(&outcome.x, false).0;
    } else {
        // Is the peak resolved? Compare with the σ → 0 limit, others refitted.
        let s2 = residual_variance(outcome.cost, 4).max(1e-300);
        let threshold = outcome.cost + CHI2_1_95 * s2;
        let sigma_hat = outcome.x[0].exp();
        let mut unresolved = false;
        if sigma_hat < 10.0 {
            // Screen: ρs, ρd solved exactly at σ → 0 and the fitted η. A resolved peak is
            // orders of magnitude worse there; only a close call needs the full refit.
            let screen = problem.linear(SIGMA_MIN_DEG, outcome.x[ETA]).cost;
            let close_call = screen - outcome.cost <= 100.0 * (threshold - outcome.cost) || screen <= 2.0 * outcome.cost;
            let mut x_floor = outcome.x;
            x_floor[0] = lo[0];
            let floor = if close_call {
                levenberg_marquardt_until(&problem, x_floor, [true, false, false, false], options.max_iterations, threshold)
            } else {
                LmOutcome { x: x_floor, cost: screen, iterations: 0, status: Status::Converged }
            };
            if close_call && floor.cost <= threshold {
                unresolved = true;
                let upper = sigma_upper_deg(&problem, &outcome, threshold, options.max_iterations);
                notes.push(Note::SigmaUnresolved { upper_deg: upper });
                fitted[SIGMA] = false;
                // The screen stopped at the threshold: finish the reduced fit.
                outcome = levenberg_marquardt(&problem, floor.x, [true, false, false, false], options.max_iterations);
            }
        }
        if !unresolved {
            if let Some(a) = options.acceptance_deg.filter(|&a| model::acceptance_matters(sigma_hat, a)) {
                problem.acceptance_deg = Some(a);
                outcome = global_fit(&problem, options.max_iterations);
            }
        }
        if outcome.x[ETA] >= hi[ETA] {
            notes.push(Note::EtaAtBound { eta: ETA_MAX });
            fitted[ETA] = false;
        } else if outcome.x[ETA] <= lo[ETA] {
            // η → 1: F ∝ (η²−1), so only the amplitude ρs·(η²−1) is determined, not ρs.
            notes.push(Note::EtaAtBound { eta: ETA_MIN });
            fitted[ETA] = false;
            fitted[RHO_S] = false;
        }
    }

    // Intervals from JᵀWJ at the optimum, on the fitted parameters off their bounds.
    let x = outcome.x;
    let (cost, a, _) = problem.accumulate(&x, true);
    let mut active_bounds = Vec::new();
    let mut free = fitted;
    for i in 0..4 {
        if !fitted[i] {
            continue;
        }
        if x[i] <= lo[i] {
            active_bounds.push(ActiveBound { param: PARAM_NAMES[i], bound: Bound::Lower });
            free[i] = false;
        } else if x[i] >= hi[i] {
            active_bounds.push(ActiveBound { param: PARAM_NAMES[i], bound: Bound::Upper });
            free[i] = false;
        }
    }
    for note in &notes {
        if let Note::EtaAtBound { eta } = note {
            let bound = if *eta >= ETA_MAX { Bound::Upper } else { Bound::Lower };
            active_bounds.push(ActiveBound { param: "eta", bound });
        }
    }
    let model = FittedModel(fitted);
    let p_fitted = model.count();
    let dof = n.saturating_sub(p_fitted);
    let weighted = problem.weighted;
    let s2 = if weighted { 1.0 } else if dof > 0 { cost / dof as f64 } else { f64::NAN };
    let mut covariance = [[0.0; 4]; 4];
    let mut ci95 = [None; 4];
    let mut ci_clipped = [false; 4];
    let params = params_of(&x);
    if dof == 0 {
        notes.push(Note::NoDegreesOfFreedom);
    } else if let Some(inv) = inverse_spd(&a, &free) {
        let t = t_quantile_975(dof);
        // d(σ, ρs, ρd, η)/d(ln σ, A, ρd, η): σ = e^x0, ρs = A/(η²−1).
        let k = eta_factor(x[3]);
        let mut jac = [[0.0; 4]; 4];
        jac[0][0] = params.sigma_deg;
        jac[1][1] = 1.0 / k;
        jac[1][3] = -x[1] * 2.0 * x[3] / (k * k);
        jac[2][2] = 1.0;
        jac[3][3] = 1.0;
        for i in 0..4 {
            for j in 0..4 {
                let mut sum = 0.0;
                for p in 0..4 {
                    for q in 0..4 {
                        sum += jac[i][p] * inv[p][q] * jac[j][q];
                    }
                }
                covariance[i][j] = s2 * sum;
            }
        }
        let natural_lo = [SIGMA_MIN_DEG, 0.0, 0.0, ETA_MIN];
        let natural_hi = [SIGMA_MAX_DEG, f64::INFINITY, f64::INFINITY, ETA_MAX];
        for i in 0..4 {
            if !free[i] {
                continue;
            }
            let (low, high) = if i == SIGMA {
                // In ln σ, so the interval stays positive and follows the lobe's scale.
                let se = (s2 * inv[0][0]).max(0.0).sqrt();
                ((x[0] - t * se).exp(), (x[0] + t * se).exp())
            } else {
                let v = params.to_array()[i];
                let se = covariance[i][i].max(0.0).sqrt();
                (v - t * se, v + t * se)
            };
            let (cl, ch) = (low.max(natural_lo[i]), high.min(natural_hi[i]));
            ci_clipped[i] = cl != low || ch != high;
            ci95[i] = Some((cl, ch));
        }
    } else if free.iter().any(|&f| f) {
        notes.push(Note::SingularJacobian);
    }

    let (mut abs_sum, mut sq_sum) = (0.0, 0.0);
    let (mut y_min, mut y_max) = (f64::INFINITY, f64::NEG_INFINITY);
    for (pt, o) in problem.points.iter().zip(observations) {
        let r = model::evaluate(&params, &pt.geometry, problem.acceptance_deg).0 - o.radiance_factor;
        abs_sum += r.abs();
        sq_sum += r * r;
        y_min = y_min.min(o.radiance_factor);
        y_max = y_max.max(o.radiance_factor);
    }
    Ok(FitResult {
        params,
        model,
        ci95,
        ci_clipped,
        covariance,
        active_bounds,
        notes,
        acceptance_deg: problem.acceptance_deg,
        n,
        cost,
        residual_variance: s2,
        dof,
        nmae: abs_sum / n as f64 / (y_max - y_min),
        rms: (sq_sum / n as f64).sqrt(),
        iterations: outcome.iterations,
        status: outcome.status,
        weighted,
    })
}

fn problem_weighted(observations: &[Observation]) -> bool {
    observations.first().is_some_and(|o| o.std.is_some())
}

fn lambert_fit(problem: &Problem) -> f64 {
    let (sw, sy) = problem.points.iter().fold((0.0, 0.0), |(sw, sy), p| {
        let w = p.sqrt_w * p.sqrt_w;
        (sw + w, sy + w * p.y)
    });
    sy / sw
}

/// Largest σ whose profile cost (others refitted) stays within `threshold`: doubling, then
/// bisection in ln σ to about 2 %.
fn sigma_upper_deg(problem: &Problem, best: &LmOutcome, threshold: f64, max_iterations: usize) -> f64 {
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
    let Some(mut outside) = outside else { return SIGMA_MAX_DEG };
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
    inside.exp()
}
