//! The arm zero: an offset δ0 of the detector arm's zero (every θr read as θr + δ0) fitted
//! when the data call for it, else the zero's stated uncertainty carried as one more
//! shared error.
//!
//! Why here: only a resolved peak has a position to shift (an unresolved one's is
//! confounded with σ; without a peak there is nothing to shift), so it follows
//! identifiability; and the covariance, which counts δ0 as a parameter when it is fitted,
//! follows it.
use super::covariance::{SANDWICH_MIN_DOF, gls_normal, sandwich};
use super::engine::{
    LeastSquaresProblem, LmOutcome, levenberg_marquardt, lower_bounds, upper_bounds,
};
use super::{
    ARM_OFFSET_LR_CRITICAL, ARM_OFFSET_MAX_DEG, ARM_ZERO, FitOptions, Observation, SharedError,
    State, at_model,
};
use crate::analysis::linalg::{self, Square};
use crate::analysis::model::{DetectorResponse, RHO_S};

/// The score statistic (the likelihood ratio's quadratic prediction from δ0 = 0) below
/// which the search for δ0 is not run (it costs a few refits). Over 675 fits of ideal and
/// slightly offset sheets (G, SG, PPC, J1, MC; full grid and Strategy 2; with and without
/// uncertainties) the likelihood ratio never exceeded 2.7 where the score was below 2,
/// far under [`ARM_OFFSET_LR_CRITICAL`]; for large offsets the two agree to 0.1 %.
const ARM_OFFSET_SCREEN: f64 = 2.0;

/// What the arm-offset step found.
pub(super) struct ArmTest {
    /// The test's statistic (likelihood ratio, or the score screen's when the search was
    /// not needed); `None` when not tested.
    pub(crate) statistic: Option<f64>,
    /// Whether δ0 was fitted (then the problem is the shifted one).
    pub fitted: bool,
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
    /// The likelihood-ratio statistic, or the score screen's when the search was skipped.
    statistic: f64,
    /// The shifted problem and its fit, when δ0 passed the test.
    accepted: Option<(LeastSquaresProblem, LmOutcome)>,
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

/// Test for an arm zero offset and fit it when the data call for it: the score statistic
/// at δ0 = 0 screens; then Gauss–Newton steps on the profile cost c(δ0) (each a rebuilt
/// problem and a warm Levenberg–Marquardt run), and the likelihood ratio (c(0) − c(δ̂0))/s²
/// against [`ARM_OFFSET_LR_CRITICAL`] (s² = 1 weighted; without uncertainties the Wald
/// statistic δ̂0²/Var(δ̂0) with the sandwich variance, or s² from the residuals below
/// [`SANDWICH_MIN_DOF`]).
fn arm_offset_search(
    observations: &[Observation],
    shared: &[SharedError],
    acceptance: Option<DetectorResponse>,
    base: &LeastSquaresProblem,
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
            let shifted = LeastSquaresProblem::new(observations, shared, acceptance, trial);
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
fn robust_arm_offset_statistic(problem: &LeastSquaresProblem, x: &[f64; 4]) -> Option<f64> {
    let (_, residuals, columns) = offset_columns(problem, x);
    let normal = gls_normal(&problem.shared, &columns, None);
    let h_inv = linalg::spd_inverse(&normal.h)?;
    let cov = sandwich(&h_inv, &columns, &residuals);
    let p = columns.len();
    let variance = cov.at(p - 1, p - 1);
    (variance > 0.0).then(|| problem.shift_deg * problem.shift_deg / variance)
}
