//! The arm zero: an offset δ0 of the detector arm's zero (every θr read as θr + δ0) fitted
//! when the data call for it, else the zero's stated uncertainty carried as one more
//! shared error.
//!
//! Why here: only a resolved peak has a position to shift (an unresolved one's is
//! confounded with σ; without a peak there is nothing to shift), so it follows
//! identifiability; and the covariance, which counts δ0 as a parameter when it is fitted,
//! follows it.
use super::covariance::gls_normal;
use super::engine::{
    LeastSquaresProblem, LmOutcome, levenberg_marquardt, lower_bounds, upper_bounds,
};
use super::{
    ARM_OFFSET_LR_CRITICAL, ARM_OFFSET_MAX_DEG, ARM_ZERO, FitOptions, FitResult, Note, Observation,
    SharedError, State, at_model,
};
use crate::analysis::flags::Flag;
use crate::analysis::linalg::{self, Square};
use crate::analysis::model::{DetectorResponse, RHO_S};
use statrs::distribution::{ContinuousCDF, Normal, StudentsT};

/// The score statistic (the likelihood ratio's quadratic prediction from δ0 = 0) below
/// which the search for δ0 is not run (it costs a few refits). Over 675 fits of ideal and
/// slightly offset sheets (G, SG, PPC, J1, MC; full grid and Strategy 2; with and without
/// uncertainties) the likelihood ratio never exceeded 2.7 where the score was below 2,
/// far under [`ARM_OFFSET_LR_CRITICAL`]; for large offsets the two agree to 0.1 %.
const ARM_OFFSET_SCREEN: f64 = 2.0;

/// Parameters of the readings' noise model without uncertainties (var = a + b·f²).
const NOISE_MODEL_PARAMS: usize = 2;

/// What the arm-offset step found.
pub(super) struct ArmTest {
    /// The test's statistic (likelihood ratio, or the score screen's when the search was
    /// not needed); `None` when not tested.
    pub(crate) statistic: Option<f64>,
    /// Whether δ0 was fitted (then the problem is the shifted one).
    pub fitted: bool,
}

/// Where the arm offset the result keeps sits at ± [`ARM_OFFSET_MAX_DEG`], the most the
/// fit looks for: flagged `lack-of-fit` with a note ([`Note::ArmOffsetAtLimit`]). The
/// readings then ask for more offset than a built instrument's zero can have (the
/// reference's is aligned to about 0.1°), and what the offset stands for is not an arm
/// zero: on a semi-gloss whose Fresnel factor is half flattened (the shapes campaign,
/// adaptive, ideal physics, so no offset at all) the offset went to −3° in 17 of 18
/// sessions, σ's interval missed the sheet's in 13 of them, and one of those, σ 1.914
/// [1.910, 1.922]° against 1.9°, was clean at confidence 1.00 (docs/ACCURACY.md).
pub(super) fn flag_at_limit(result: &mut FitResult) {
    let Some(offset) = &result.arm_offset else {
        return;
    };
    if offset.deg.abs() < ARM_OFFSET_MAX_DEG * (1.0 - 1e-6) {
        return;
    }
    result
        .notes
        .push(Note::ArmOffsetAtLimit { deg: offset.deg });
    if !result.flags.contains(&Flag::LackOfFit) {
        result.flags.push(Flag::LackOfFit);
    }
}

/// Test for an arm zero offset where the peak is resolved ([`arm_offset_search`]) and,
/// when the data call for one, take the shifted problem and its fit. With shared errors
/// their scaling parts were evaluated at the first pass's model, which had no offset:
/// they are evaluated again at the shifted model, and the fit redone with them.
pub(super) fn test_and_fit(
    state: &mut State,
    observations: &[Observation],
    given: &[SharedError],
    acceptance: Option<DetectorResponse>,
    unresolved: bool,
    options: &FitOptions,
) -> ArmTest {
    let mut test = ArmTest {
        statistic: None,
        fitted: false,
    };
    if !(options.arm_offset && !unresolved && state.fitted[RHO_S]) {
        return test;
    }
    let fitted_count = state.fitted.iter().filter(|&&b| b).count();
    let search = arm_offset_search(
        observations,
        &state.shared,
        acceptance,
        &state.problem,
        &state.outcome,
        fitted_count,
        options.max_iterations,
    );
    test.statistic = Some(search.statistic);
    if let Some((shifted, refit)) = search.accepted {
        if given.is_empty() {
            (state.problem, state.outcome) = (shifted, refit);
        } else {
            let values = shifted.values(&refit.x);
            state.shared = at_model(given, observations, Some(&values));
            state.problem = LeastSquaresProblem::new(
                observations,
                &state.shared,
                acceptance,
                shifted.shift_deg,
            );
            state.outcome =
                levenberg_marquardt(&state.problem, refit.x, [false; 4], options.max_iterations);
        }
        test.fitted = true;
    }
    test
}

/// An offset too small for the test to call for is still possible: the arm zero's
/// uncertainty ([`FitOptions::arm_zero_uncertainty_deg`]) as a shared error, ∂f/∂θr at the
/// model times it, and the fit redone with it (weighted fits with a specular part only).
pub(super) fn zero_uncertainty(
    state: &mut State,
    observations: &[Observation],
    acceptance: Option<DetectorResponse>,
    options: &FitOptions,
) {
    let u = options.arm_zero_uncertainty_deg;
    if !(u > 0.0 && u.is_finite() && state.fitted[RHO_S] && state.problem.weighted) {
        return;
    }
    let whitened = state.problem.shift_column(&state.outcome.x);
    let additive: Vec<f64> = whitened
        .iter()
        .zip(observations)
        .map(|(d, o)| d * o.std.unwrap_or(1.0) * u)
        .collect();
    if additive.iter().all(|v| v.is_finite()) && additive.iter().any(|v| *v != 0.0) {
        state.shared.push(SharedError {
            name: ARM_ZERO.to_string(),
            sensitivity: additive,
            additive: Vec::new(),
        });
        state.problem = LeastSquaresProblem::new(observations, &state.shared, acceptance, 0.0);
        let fixed = std::array::from_fn(|i| !state.fitted[i]);
        state.outcome = levenberg_marquardt(
            &state.problem,
            state.outcome.x,
            fixed,
            options.max_iterations,
        );
    }
}

/// What the arm-offset test found.
struct ArmSearch {
    /// The test's statistic (on the χ²(1) scale), or the score screen's when the search
    /// was skipped.
    statistic: f64,
    /// The shifted problem and its fit, when δ0 passed the test.
    accepted: Option<(LeastSquaresProblem, LmOutcome)>,
}

/// The test for an arm zero offset: weighted, the likelihood ratio; without uncertainties,
/// [`unweighted_search`].
fn arm_offset_search(
    observations: &[Observation],
    shared: &[SharedError],
    acceptance: Option<DetectorResponse>,
    base: &LeastSquaresProblem,
    outcome: &LmOutcome,
    fitted_count: usize,
    max_iterations: usize,
) -> ArmSearch {
    if !base.weighted {
        return unweighted_search(
            observations,
            shared,
            acceptance,
            base,
            outcome,
            fitted_count,
            max_iterations,
        );
    }
    // Weighted: the noise variance is known (s² = 1) and the likelihood ratio
    // c(0) − c(δ̂0) is χ²(1) under no offset.
    let context = SearchContext {
        observations,
        shared,
        acceptance,
        max_iterations,
    };
    let (score, best) = profile_search(&context, base, outcome, 1.0, ARM_OFFSET_SCREEN);
    let Some((problem, run)) = best else {
        return ArmSearch {
            statistic: score,
            accepted: None,
        };
    };
    let lr = outcome.cost - run.cost;
    ArmSearch {
        statistic: lr,
        accepted: (lr > ARM_OFFSET_LR_CRITICAL).then_some((problem, run)),
    }
}

/// What every profile search is made with besides its base problem.
struct SearchContext<'a> {
    observations: &'a [Observation],
    shared: &'a [SharedError],
    acceptance: Option<DetectorResponse>,
    max_iterations: usize,
}

/// Without uncertainties the readings' noise is unknown, and not equal: a detector's is a
/// floor plus a part proportional to the signal, so a peak's readings are far noisier than
/// its flanks'. The statistics used before did not hold their 1 % level on short
/// schedules (exact-TSL data sets of the eight papers, 1 % + 0.003 noise, 100 seeds per
/// paper and schedule): the equal-noise likelihood ratio (below 20 degrees of freedom,
/// where the HC3 sandwich is too unstable) fired in 31 of 800 Strategy 1 sets (SG 14 of
/// 100); the sandwich's Wald statistic against χ²(1) in 8 of 800 full-grid and 10 of 800
/// Strategy 2 (δ = 2°) sets, at its level there, but resting on one residual per reading.
/// So the noise is modelled instead: var = a + b·f² fitted to the base fit's squared
/// residuals ([`noise_model`]), the readings weighted by it, and the extra-sum-of-squares
/// F test on the weighted costs, its scale estimated from them (ν = n − p − 1; the
/// reference F(1, ν − 2) for the noise model's two parameters), reported as the χ²(1)
/// statistic of the same p-value so that it is compared with [`ARM_OFFSET_LR_CRITICAL`]
/// like the weighted one: 8, 11 and 4 of those 800 sets. The test only decides: an offset
/// it calls for is then fitted on the readings as given (the equal-weight profile's
/// optimum), which is what the unweighted covariance that follows assumes.
fn unweighted_search(
    observations: &[Observation],
    shared: &[SharedError],
    acceptance: Option<DetectorResponse>,
    base: &LeastSquaresProblem,
    outcome: &LmOutcome,
    fitted_count: usize,
    max_iterations: usize,
) -> ArmSearch {
    let none = |statistic: f64| ArmSearch {
        statistic,
        accepted: None,
    };
    let n = observations.len();
    // Too few readings to estimate the noise with δ0 fitted: nothing to test with.
    let Some(nu) = n.checked_sub(fitted_count + 1).filter(|&v| v >= 1) else {
        return none(0.0);
    };
    let given = SearchContext {
        observations,
        shared,
        acceptance,
        max_iterations,
    };
    let Some((weighted_observations, weighted_base, weighted_fit)) =
        noise_model(&given, base, outcome)
    else {
        return none(0.0);
    };
    let s2 = weighted_fit.cost / (nu + 1) as f64;
    let context = SearchContext {
        observations: &weighted_observations,
        shared,
        acceptance,
        max_iterations,
    };
    let (score, best) = profile_search(
        &context,
        &weighted_base,
        &weighted_fit,
        s2,
        ARM_OFFSET_SCREEN,
    );
    let Some((weighted_problem, run)) = best else {
        return none(score);
    };
    let f = (weighted_fit.cost - run.cost).max(0.0) / (run.cost / nu as f64).max(1e-300);
    // The weights' two parameters were estimated from the same residuals: the reference
    // has their degrees of freedom fewer (on Strategy 1's 12 readings the test fired in
    // 14 of 800 exact-TSL sets with F(1, ν), in 4 with F(1, ν − 2)).
    let statistic = chi2_equivalent(f, nu.saturating_sub(NOISE_MODEL_PARAMS).max(1) as f64);
    if statistic <= ARM_OFFSET_LR_CRITICAL {
        return none(statistic);
    }
    // Called for: δ0 and the rest fitted on the readings as given.
    let s2_given = outcome.cost / (nu + 1) as f64;
    let (_, best) = profile_search(&given, base, outcome, s2_given, f64::NEG_INFINITY);
    let accepted = best.or_else(|| {
        // The equal-weight profile found nothing better than δ0 = 0 (its minimum is
        // elsewhere than the weighted one's): δ0 as the weighted test found it.
        let shifted =
            LeastSquaresProblem::new(observations, shared, acceptance, weighted_problem.shift_deg);
        let refit = levenberg_marquardt(&shifted, run.x, [false; 4], max_iterations);
        Some((shifted, refit))
    });
    ArmSearch {
        statistic,
        accepted,
    }
}
/// At `x` on `problem`: the parameters off their bounds, the whitened residuals, and the
/// whitened Jacobian's columns of those parameters with δ0's last.
fn offset_columns(
    problem: &LeastSquaresProblem,
    x: &[f64; 4],
) -> (Vec<usize>, Vec<f64>, Vec<Vec<f64>>) {
    let (lo, hi) = (lower_bounds(), upper_bounds());
    let (residuals, jacobian) = problem.rows(x);
    let free: Vec<usize> = (0..4).filter(|&i| x[i] > lo[i] && x[i] < hi[i]).collect();
    let mut columns: Vec<Vec<f64>> = free
        .iter()
        .map(|&i| jacobian.iter().map(|row| row[i]).collect())
        .collect();
    columns.push(problem.shift_column(x));
    (free, residuals, columns)
}

/// The joint Gauss–Newton step in (free x, δ0) at `outcome` on `problem`, and the score
/// statistic of δ0 (the part of the predicted decrease of the cost due to δ0).
fn arm_offset_step(
    problem: &LeastSquaresProblem,
    x: &[f64; 4],
) -> Option<(Vec<usize>, Vec<f64>, f64, f64)> {
    let (free, residuals, columns) = offset_columns(problem, x);
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

/// Gauss–Newton steps on the profile cost c(δ0) from δ0 = 0 on `base` (each a rebuilt
/// problem and a warm Levenberg–Marquardt run), after a screen: the score statistic at
/// δ0 = 0 in units of `s2`, below `screen` no search. The score, and the best shifted
/// problem with its fit when one lowered the cost.
fn profile_search(
    context: &SearchContext,
    base: &LeastSquaresProblem,
    outcome: &LmOutcome,
    s2: f64,
    screen: f64,
) -> (f64, Option<(LeastSquaresProblem, LmOutcome)>) {
    let Some((free, step, score, se)) = arm_offset_step(base, &outcome.x) else {
        return (0.0, None);
    };
    let score = score / s2.max(1e-300);
    // Converged when the next step is a twentieth of δ0's standard error: the cost is then
    // within 0.0025 (in noise-variance units) of its minimum, far below any level tested.
    let tolerance = 0.05 * se * s2.sqrt();
    if score.is_nan() || score < screen {
        return (score, None);
    }
    let (lo, hi) = (lower_bounds(), upper_bounds());
    let mut best: Option<(LeastSquaresProblem, LmOutcome)> = None;
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
            let shifted = LeastSquaresProblem::new(
                context.observations,
                context.shared,
                context.acceptance,
                trial,
            );
            let fraction = if step[step.len() - 1] != 0.0 {
                d_delta / step[step.len() - 1]
            } else {
                0.0
            };
            let mut x0 = current_x;
            for (c, &i) in free.iter().enumerate() {
                x0[i] = (x0[i] + fraction * step[c]).clamp(lo[i], hi[i]);
            }
            let run = levenberg_marquardt(&shifted, x0, [false; 4], context.max_iterations);
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
    (score, best)
}

/// The readings weighted by a variance function var = a + b·f² (a detector's floor and
/// its part proportional to the signal, f the model value) fitted to the squared
/// residuals of the fit on `base`, and the fit with those weights. Each squared residual
/// is first divided by 1 − h, h its reading's leverage: a glossy peak's few readings
/// carry most of σ, ρs and η, so the fit passes close to them, and without it their
/// variance came out far too small, their weight too large, and the test fired on G's
/// Strategy 2 at δ = 2° in 15 of 150 data sets. Three passes, each refitting with the
/// weights of the last and regressing by 1/var² (a squared residual's variance is
/// 2·var²), so that the peak's large residuals do not set the floor. The variances are
/// scaled to a mean of 1 (the test estimates the scale). `None` when the residuals say
/// nothing (all zero, or not finite).
fn noise_model(
    context: &SearchContext,
    base: &LeastSquaresProblem,
    outcome: &LmOutcome,
) -> Option<(Vec<Observation>, LeastSquaresProblem, LmOutcome)> {
    let n = context.observations.len();
    let mut variances = vec![1.0; n];
    let mut current: Option<(Vec<Observation>, LeastSquaresProblem, LmOutcome)> = None;
    for _ in 0..3 {
        let (problem, fit) = match &current {
            Some((_, problem, fit)) => (problem, fit),
            None => (base, outcome),
        };
        let values = problem.values(&fit.x);
        let leverages = leverages(problem, &fit.x)?;
        let residuals: Vec<f64> = context
            .observations
            .iter()
            .zip(&values)
            .map(|(o, f)| o.radiance_factor - f)
            .collect();
        variances = linalg::variance_step(&values, &residuals, &leverages, &variances)?;
        let mean = variances.iter().sum::<f64>() / n as f64;
        for v in &mut variances {
            *v /= mean;
        }
        let weighted: Vec<Observation> = context
            .observations
            .iter()
            .zip(&variances)
            .map(|(o, v)| Observation {
                std: Some(v.sqrt()),
                ..*o
            })
            .collect();
        let problem = LeastSquaresProblem::new(&weighted, context.shared, context.acceptance, 0.0);
        let fit = levenberg_marquardt(&problem, fit.x, [false; 4], context.max_iterations);
        current = Some((weighted, problem, fit));
    }
    current
}

/// Each reading's leverage in the fit at `x` on `problem` (the parameters off their
/// bounds): the diagonal of the whitened hat matrix J (JᵀJ)⁻¹ Jᵀ.
fn leverages(problem: &LeastSquaresProblem, x: &[f64; 4]) -> Option<Vec<f64>> {
    let (_, _, mut columns) = offset_columns(problem, x);
    columns.pop();
    let p = columns.len();
    let mut h = Square::zeros(p);
    for i in 0..p {
        for j in 0..p {
            *h.at_mut(i, j) = columns[i].iter().zip(&columns[j]).map(|(a, b)| a * b).sum();
        }
    }
    let inverse = linalg::spd_inverse(&h)?;
    let n = columns.first().map_or(0, Vec::len);
    Some(
        (0..n)
            .map(|k| {
                (0..p)
                    .map(|i| {
                        (0..p)
                            .map(|j| columns[i][k] * inverse.at(i, j) * columns[j][k])
                            .sum::<f64>()
                    })
                    .sum::<f64>()
                    .clamp(0.0, 1.0)
            })
            .collect(),
    )
}

/// The χ²(1) statistic with the p-value of `f` under F(1, ν): F(1, ν) is t(ν)², so it is
/// the squared standard normal deviate of t's two-sided tail at √f.
fn chi2_equivalent(f: f64, nu: f64) -> f64 {
    let (Ok(t), Ok(normal)) = (StudentsT::new(0.0, 1.0, nu), Normal::new(0.0, 1.0)) else {
        return 0.0;
    };
    let tail = t.sf(f.max(0.0).sqrt());
    if tail <= 0.0 {
        return f;
    }
    normal.inverse_cdf(tail).powi(2)
}
