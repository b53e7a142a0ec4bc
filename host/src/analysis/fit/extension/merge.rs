//! The chosen member into the result: its main lobe, goodness of fit, covariance and
//! intervals; then the intervals widened for the members the data cannot exclude.
use super::family::Param;
use super::solver::Problem;
use super::{Base, Member, Term, main_lobe, result_index};
use crate::analysis::fit::covariance::{Z_975, interval_95};
use crate::analysis::fit::validation::geometry_order;
use crate::analysis::fit::{
    BudgetTerm, ETA_MAX, ETA_MIN, FitResult, N_PARAMS, Note, t_quantile_975,
};
use crate::analysis::flags::Flag;
use crate::analysis::gof;
use crate::analysis::model::{ETA, RHO_D, RHO_S, SIGMA};

/// Name of the budget term that widens the intervals for model form.
pub const MODEL_FORM: &str = "model form";
/// Largest lag-1 autocorrelation used in the widening factor (as the base fit's).
const WIDENING_MAX_LAG1: f64 = 0.9;

/// The chosen member's goodness of fit, as the base fit judges its own: χ² (weighted),
/// the residual-structure test on the decorrelated residuals, the widening they call for.
struct MemberGoodness {
    chi2: Option<f64>,
    gof_p: Option<f64>,
    structure: Option<gof::StructureTest>,
    lack_of_fit: bool,
    widening: f64,
}

fn member_goodness(
    base: &Base,
    weighted: bool,
    problem: &Problem,
    fit: &super::MemberFit,
    dof: usize,
) -> MemberGoodness {
    let order = geometry_order(base.observations);
    let (s, m) = problem.shared_row_major();
    let decorrelated = gof::innovations(&fit.residuals, &s, m, &order);
    let theta_i: Vec<f64> = order
        .iter()
        .map(|&i| base.observations[i].theta_i_deg)
        .collect();
    let structure = gof::structure_test(&theta_i, &decorrelated);
    let (chi2, gof_p) = if weighted {
        (
            Some(fit.cost),
            gof::chi2_upper_tail_scaled(fit.cost, dof, base.options.noise_scale_log_variance),
        )
    } else {
        (None, None)
    };
    let lack_of_fit = gof_p.is_some_and(|p| p < gof::GOF_ALPHA)
        || structure.is_some_and(|s| s.p_value < gof::STRUCTURE_ALPHA);
    let widening = if lack_of_fit {
        let birge = chi2.map_or(1.0, |c| (c / dof.max(1) as f64).max(1.0));
        let rho = structure.map_or(0.0, |s| s.lag1.clamp(0.0, WIDENING_MAX_LAG1));
        birge * (1.0 + rho) / (1.0 - rho)
    } else {
        1.0
    };
    MemberGoodness {
        chi2,
        gof_p,
        structure,
        lack_of_fit,
        widening,
    }
}

/// NMAE and RMS of the chosen member's residuals (and the noise of one reading without
/// uncertainties).
fn residual_summaries(
    base: &Base,
    result: &mut FitResult,
    problem: &Problem,
    fit: &super::MemberFit,
    dof: usize,
) {
    let n = problem.len();
    let raw = problem.raw_residuals(&fit.residuals);
    let (y_min, y_max) = base
        .observations
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), o| {
            (a.min(o.radiance_factor), b.max(o.radiance_factor))
        });
    result.nmae = raw.iter().map(|r| r.abs()).sum::<f64>() / n as f64 / (y_max - y_min);
    result.rms = (raw.iter().map(|r| r * r).sum::<f64>() / n as f64).sqrt();
    if !result.weighted {
        // One reading's noise if it were the same for all (the weights came from a
        // variance function, [`Problem::weigh_by_noise_model`]).
        result.noise_from_residuals = Some(result.rms * (n as f64 / dof.max(1) as f64).sqrt());
    }
}

/// The result takes the chosen member's main lobe, its goodness of fit and its
/// covariance (with the shared errors in it, the solver's module docs), widened under
/// lack of fit as the base fit widens its own.
pub(super) fn take_member(base: &Base, result: &mut FitResult, problem: &Problem, chosen: &Member) {
    let fit = &chosen.fit;
    let n = problem.len();
    let dof = n.saturating_sub(fit.active.len());
    let MemberGoodness {
        chi2,
        gof_p,
        structure,
        lack_of_fit,
        widening,
    } = member_goodness(base, result.weighted, problem, fit, dof);
    let s2 = if result.weighted {
        1.0
    } else {
        fit.cost / dof.max(1) as f64
    };
    let variance_scale = widening * s2;
    let estimates = main_lobe(&fit.values);
    let mut covariance = [[0.0; N_PARAMS]; N_PARAMS];
    if let Some(c) = &fit.covariance {
        // σ is fitted as ln σ: dσ = σ · d ln σ.
        let scale = |p: Param| {
            if p == Param::LnSigma {
                estimates[SIGMA]
            } else {
                1.0
            }
        };
        for (a, pa) in fit.active.iter().enumerate() {
            for (b, pb) in fit.active.iter().enumerate() {
                if let (Some(i), Some(j)) = (result_index(*pa), result_index(*pb)) {
                    covariance[i][j] = c.at(a, b) * scale(*pa) * scale(*pb) * variance_scale;
                }
            }
        }
    }
    let q = if result.weighted && !lack_of_fit {
        Z_975
    } else {
        t_quantile_975(dof)
    };
    let active_index: Vec<usize> = fit.active.iter().filter_map(|p| result_index(*p)).collect();
    for i in 0..N_PARAMS {
        if !active_index.contains(&i) {
            continue;
        }
        let sd = covariance[i][i].max(0.0).sqrt();
        let (interval, clipped) = interval_95(i, estimates[i], sd, q);
        result.ci_clipped[i] = clipped;
        result.ci95[i] = fit.covariance.as_ref().map(|_| interval);
    }
    let mut params = result.params.to_array();
    for &i in &active_index {
        params[i] = estimates[i];
    }
    if active_index.contains(&ETA) && !base.fitted[ETA] {
        // η came off the bound the base fit held it at.
        if estimates[ETA] > ETA_MIN && estimates[ETA] < ETA_MAX {
            result
                .notes
                .retain(|n| !matches!(n, Note::EtaAtBound { .. }));
            result.model.0[ETA] = true;
        }
    }
    result.params = crate::analysis::model::Params::from_array(params);
    if !lack_of_fit {
        // The base model's misfit is what the terms took up: no widening for it is left.
        result
            .budget
            .retain(|t| t.name != crate::analysis::budget::LACK_OF_FIT);
    }
    let old_diagonal: [f64; N_PARAMS] =
        std::array::from_fn(|i| result.budget.iter().map(|t| t.variance[i]).sum::<f64>());
    rescale_budget(&mut result.budget, &old_diagonal, &covariance);
    result.covariance = covariance;
    if let (Some(arm), Some(sd)) = (result.arm_offset.as_mut(), fit.std_of(Param::Shift)) {
        arm.deg = fit.values[Param::Shift as usize];
        arm.std_deg = sd * variance_scale.sqrt();
        arm.ci95 = (arm.deg - q * arm.std_deg, arm.deg + q * arm.std_deg);
        for note in result.notes.iter_mut() {
            if let Note::ArmOffsetFitted { deg, std_deg, .. } = note {
                (*deg, *std_deg) = (arm.deg, arm.std_deg);
            }
        }
    }
    residual_summaries(base, result, problem, fit, dof);
    result.cost = fit.cost;
    result.chi2 = chi2;
    result.gof_p = gof_p;
    result.structure = structure;
    result.dof = dof;
    result.lack_of_fit = lack_of_fit;
    result.variance_scale = widening;
    result.residual_variance = variance_scale;
    result
        .notes
        .retain(|n| !matches!(n, Note::IntervalsWidened { .. }));
    if widening > 1.0 {
        result
            .notes
            .push(Note::IntervalsWidened { factor: widening });
    }
    result.flags.retain(|f| *f != Flag::LackOfFit);
    if lack_of_fit {
        result.flags.push(Flag::LackOfFit);
    }
    result.flags.push(Flag::ModelExtended);
}

/// The budget's terms scaled so that they add up to the chosen member's variances (each
/// source keeps its share; the member's covariance is not split by source).
fn rescale_budget(
    budget: &mut [BudgetTerm],
    old_diagonal: &[f64; N_PARAMS],
    covariance: &[[f64; N_PARAMS]; N_PARAMS],
) {
    for i in 0..N_PARAMS {
        let ratio = if old_diagonal[i] > 0.0 {
            covariance[i][i] / old_diagonal[i]
        } else {
            0.0
        };
        for term in budget.iter_mut() {
            term.variance[i] *= ratio;
        }
    }
}

/// Widen σ, ρs, ρd, η's intervals to cover the intervals of every member within
/// [`super::AKAIKE_PLAUSIBLE`] of the best; the covariance's diagonal grows with them (the
/// budget's `model form` term). Returns those members' labels.
///
/// A member's interval, not only its estimate: a member with one more term than the chosen
/// one (always within 2, its term not called for but not excluded either) holds in its
/// covariance how far that term, free, lets σ, ρs, ρd, η move (a tail against σ, a body
/// against η), which is what the data leave open between the shapes; its estimate alone
/// is where the term fitted to nothing, the chosen member's own.
pub(super) fn widen_for_model_form(
    result: &mut FitResult,
    members: &[Member],
    chosen: &Member,
    n: usize,
    weighted: bool,
    theta_i_range: (f64, f64),
) -> Vec<String> {
    let dof = n.saturating_sub(chosen.fit.active.len()).max(1);
    let s2 = if weighted {
        (chosen.fit.cost / dof as f64).max(1.0)
    } else {
        (chosen.fit.cost / dof as f64).max(f64::MIN_POSITIVE)
    };
    let akaike = |m: &Member| m.fit.cost / s2 + 2.0 * m.fit.active.len() as f64;
    let best = members.iter().map(akaike).fold(f64::INFINITY, f64::min);
    let chosen_label = chosen.label();
    let plausible: Vec<&Member> = members
        .iter()
        .filter(|m| m.label() != chosen_label)
        .filter(|m| akaike(m) - best <= super::AKAIKE_PLAUSIBLE)
        .collect();
    let mut extra = [0.0; N_PARAMS];
    for i in [SIGMA, RHO_S, RHO_D, ETA] {
        let Some((mut lo, mut hi)) = result.ci95[i] else {
            continue;
        };
        let (lo0, hi0) = (lo, hi);
        for m in &plausible {
            let (a, b) = member_interval(m, i, n, weighted, result.variance_scale);
            lo = lo.min(a);
            hi = hi.max(b);
        }
        if i == SIGMA {
            // How σ varies between the θi measured is not known, only its values there:
            // σ at the reference θi, interpolated as the family does (geometrically),
            // is as likely as interpolated linearly. The interval holds both, for every
            // member with a slope.
            for m in plausible.iter().copied().chain([chosen]) {
                if let Some(ratio) = linear_over_geometric(m, theta_i_range) {
                    let (a, b) = if std::ptr::eq(m, chosen) {
                        (lo0, hi0)
                    } else {
                        member_interval(m, i, n, weighted, result.variance_scale)
                    };
                    lo = lo.min(a * ratio);
                    hi = hi.max(b * ratio);
                }
            }
        }
        if lo < lo0 || hi > hi0 {
            result.ci95[i] = Some((lo, hi));
            // The widened interval as ± 1.96 sd: the variance it implies, beyond what the
            // chosen member's covariance holds.
            let sd = (hi - lo) / (2.0 * Z_975);
            extra[i] = (sd * sd - result.covariance[i][i]).max(0.0);
            result.covariance[i][i] += extra[i];
        }
    }
    if extra.iter().any(|&e| e > 0.0) {
        result.budget.push(BudgetTerm {
            name: MODEL_FORM.to_string(),
            variance: extra,
        });
    }
    eta_and_body(result, chosen, &plausible);
    plausible.iter().map(|m| m.label()).collect()
}

/// For a member whose σ varies with θi: σ at the reference θi interpolated linearly
/// between its values at the extremes of the θi measured, over σ as the member has it
/// (interpolated geometrically). None without a slope or with θi not on both sides of the
/// reference.
fn linear_over_geometric(m: &Member, (lo, hi): (f64, f64)) -> Option<f64> {
    use super::family::REFERENCE_THETA_I_DEG as REF;
    if !m.terms.contains(&Term::SigmaSlope) || !(lo < REF && hi > REF) {
        return None;
    }
    let v = &m.fit.values;
    let ln_sigma = |t: f64| v[Param::LnSigma as usize] + v[Param::Slope as usize] * (t - REF) / REF;
    let (s_lo, s_hi) = (ln_sigma(lo).exp(), ln_sigma(hi).exp());
    let linear = s_lo + (s_hi - s_lo) * (REF - lo) / (hi - lo);
    let ratio = linear / ln_sigma(REF).exp();
    ratio.is_finite().then_some(ratio)
}

/// A member's 95 % interval of σ, ρs, ρd or η (by the result's index), its variance
/// scaled as the chosen member's is (by its own χ²/ν where that exceeds 1, or the residual
/// variance without uncertainties, and the lack-of-fit widening `widening`); its estimate
/// alone where it has no covariance or does not fit that parameter; an empty interval
/// (+∞, −∞) where the estimate is not finite.
fn member_interval(
    m: &Member,
    index: usize,
    n: usize,
    weighted: bool,
    widening: f64,
) -> (f64, f64) {
    let value = main_lobe(&m.fit.values)[index];
    if !value.is_finite() {
        return (f64::INFINITY, f64::NEG_INFINITY);
    }
    let param = match index {
        SIGMA => Param::LnSigma,
        RHO_S => Param::RhoS,
        RHO_D => Param::RhoD,
        _ => Param::Eta,
    };
    let Some(sd) = m
        .fit
        .std_of(param)
        .filter(|_| m.fit.active.contains(&param))
    else {
        return (value, value);
    };
    let dof = n.saturating_sub(m.fit.active.len()).max(1);
    let ratio = m.fit.cost / dof as f64;
    let s2 = if weighted { ratio.max(1.0) } else { ratio };
    // σ is fitted as ln σ: its sd in degrees is σ times ln σ's.
    let sd = sd * (s2 * widening).sqrt() * if index == SIGMA { value } else { 1.0 };
    let q = if weighted { Z_975 } else { t_quantile_975(dof) };
    let ((lo, hi), _) = interval_95(index, value, sd, q);
    if lo.is_finite() && hi.is_finite() {
        (lo, hi)
    } else {
        (value, value)
    }
}

/// η moved by letting the body be non-Lambertian: said, and the interval covers both.
fn eta_and_body(result: &mut FitResult, chosen: &Member, plausible: &[&Member]) {
    let Some(sd) = chosen.fit.std_of(Param::Eta) else {
        return;
    };
    let with_body =
        |m: &Member| m.terms.contains(&Term::Body) || m.terms.contains(&Term::FresnelBody);
    let eta = |m: &Member| m.fit.values[Param::Eta as usize];
    let scale = if result.weighted {
        1.0
    } else {
        result.residual_variance.sqrt()
    };
    for other in plausible {
        if with_body(other) == with_body(chosen) {
            continue;
        }
        let (lambert, body) = if with_body(chosen) {
            (eta(other), eta(chosen))
        } else {
            (eta(chosen), eta(other))
        };
        if (lambert - body).abs() > 2.0 * sd * scale {
            result.notes.push(Note::EtaAbsorbsBody {
                eta_lambert: lambert,
                eta_body: body,
            });
            return;
        }
    }
}
