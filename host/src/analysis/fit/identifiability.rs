//! What the data cannot determine, taken out of the model and said so: no specular part
//! at all (a lobe that does not beat a constant), a peak the sampling does not resolve
//! (σ → 0 as good as the fit), η at a bound, and the parameters left on their bounds.
//!
//! Why before the arm offset: an offset shifts the peak, so it is only looked for where
//! there is a resolved peak; η's bound and the active bounds are read after it, on the
//! model its refits leave.
use super::engine::{
    self, LeastSquaresProblem, LmOutcome, levenberg_marquardt, levenberg_marquardt_until,
    lower_bounds, params_of, upper_bounds,
};
use super::result::eta_at_floor_of;
use super::{
    ActiveBound, Bound, ETA_MAX, ETA_MIN, FitOptions, N_PARAMS, Note, SIGMA_MAX_DEG, SIGMA_MIN_DEG,
    State,
};
use crate::analysis::model::{DetectorResponse, ETA, PARAM_NAMES, RHO_S, SIGMA};

/// χ²(1) at 95 %: a profile within this (× residual variance) of the minimum is consistent.
const CHI2_1_95: f64 = 3.841_458_820_694_124;
/// χ²(3) at 95 %.
const CHI2_3_95: f64 = 7.814_727_903_251_178;

/// Is there a specular part at all, and is its peak resolved? A lobe that improves on a
/// constant by less than χ²(3) at 95 % (× residual variance) is noise being fitted: the
/// three extra parameters are not supported, and only ρd remains. Otherwise σ is compared
/// with its σ → 0 limit ([`sigma_unresolved`]). Returns whether σ is unresolved.
pub(super) fn specular_part(
    state: &mut State,
    acceptance: Option<DetectorResponse>,
    options: &FitOptions,
) -> bool {
    let State {
        problem,
        outcome,
        notes,
        fitted,
        ..
    } = state;
    let lambert_cost = problem
        .accumulate(&[0.0, 0.0, problem.lambert(), ETA_MAX], false)
        .0;
    let no_lobe =
        (lambert_cost - outcome.cost) <= CHI2_3_95 * residual_variance(problem, outcome.cost, 4);
    if no_lobe || outcome.x[RHO_S] <= lower_bounds()[RHO_S] {
        // F ≡ 0 or ρs = 0: the specular part is absent and only ρd remains.
        notes.push(Note::NoSpecularTerm);
        *fitted = [false, false, true, false];
        let x = [outcome.x[0], 0.0, problem.lambert(), ETA_MAX];
        *outcome = LmOutcome {
            x,
            cost: problem.accumulate(&x, false).0,
            ..*outcome
        };
        return false;
    }
    let Some((outcome_floor, note)) =
        sigma_unresolved(problem, outcome, acceptance, options.max_iterations)
    else {
        return false;
    };
    notes.push(note);
    fitted[SIGMA] = false;
    *outcome = outcome_floor;
    true
}

/// The noise variance a cost stands for: 1 with uncertainties, else the cost over the
/// degrees of freedom left by `p` parameters.
fn residual_variance(problem: &LeastSquaresProblem, cost: f64, p: usize) -> f64 {
    if problem.weighted {
        1.0
    } else {
        cost / (problem.points.len().saturating_sub(p).max(1)) as f64
    }
}

/// Is the peak resolved? Compared with the σ → 0 limit, the others refitted; when that
/// limit is within χ²(1) at 95 % of the best, the reduced fit at the σ floor and the note
/// with σ's upper limit.
fn sigma_unresolved(
    problem: &LeastSquaresProblem,
    outcome: &LmOutcome,
    acceptance: Option<DetectorResponse>,
    max_iterations: usize,
) -> Option<(LmOutcome, Note)> {
    let lo = lower_bounds();
    let s2 = residual_variance(problem, outcome.cost, 4).max(1e-300);
    let threshold = outcome.cost + CHI2_1_95 * s2;
    let sigma_hat = outcome.x[0].exp();
    let small = sigma_hat < 10.0;
    if !small {
        return None;
    }
    // Screen: ρs, ρd solved exactly at σ → 0 and the fitted η. A resolved peak is
    // orders of magnitude worse there; only a close call needs the full refit.
    let screen = problem.linear(SIGMA_MIN_DEG, outcome.x[ETA]).cost;
    let close_call =
        screen - outcome.cost <= 100.0 * (threshold - outcome.cost) || screen <= 2.0 * outcome.cost;
    let mut x_floor = outcome.x;
    x_floor[0] = lo[0];
    if !close_call {
        return None;
    }
    // ρs at the floor from the closed form (through a window it must grow as
    // 1/σ to keep the specular readings), then the reduced fit to the threshold.
    let start = problem.linear(SIGMA_MIN_DEG, outcome.x[ETA]);
    x_floor[1] = start.rho_s * engine::eta_factor(outcome.x[ETA]);
    x_floor[2] = start.rho_d;
    let floor = levenberg_marquardt_until(
        problem,
        x_floor,
        [true, false, false, false],
        max_iterations,
        threshold,
    );
    let within = floor.cost <= threshold;
    if !within {
        return None;
    }
    let (upper, x_upper) = sigma_upper_deg(problem, outcome, threshold, max_iterations);
    let rho_s_lower = acceptance.map(|_| params_of(&x_upper).rho_s);
    let note = Note::SigmaUnresolved {
        upper_deg: upper,
        rho_s_lower,
    };
    // The screen stopped at the threshold: finish the reduced fit.
    let finished = levenberg_marquardt(
        problem,
        floor.x,
        [true, false, false, false],
        max_iterations,
    );
    Some((finished, note))
}

/// Largest σ whose profile cost (others refitted) stays within `threshold`, and the
/// parameters there: doubling, then bisection in ln σ to about 2 %.
fn sigma_upper_deg(
    problem: &LeastSquaresProblem,
    best: &LmOutcome,
    threshold: f64,
    max_iterations: usize,
) -> (f64, [f64; 4]) {
    let profile = |ln_sigma: f64, start: &[f64; 4]| {
        let mut x = *start;
        x[0] = ln_sigma;
        levenberg_marquardt(problem, x, [true, false, false, false], max_iterations)
    };
    let ln_sigma = best.x[0];
    let limit = profile_upper_limit(
        ProfileWalk {
            inside: ln_sigma,
            first_trial: ln_sigma + std::f64::consts::LN_2,
            max: SIGMA_MAX_DEG.ln(),
            tolerance: 0.02,
        },
        best.x,
        threshold,
        profile,
        |_| {},
    );
    let upper = if limit.reached_max {
        SIGMA_MAX_DEG
    } else {
        limit.inside.exp()
    };
    (upper, limit.at)
}

/// How [`profile_upper_limit`] walks a coordinate up: from a value known inside, the first
/// trial, then steps of ln 2 (doubling where the coordinate is a logarithm) up to `max`,
/// and bisection between the last inside and the first outside to `tolerance`.
struct ProfileWalk {
    inside: f64,
    first_trial: f64,
    max: f64,
    tolerance: f64,
}

/// Where a profile's walk stopped: the largest coordinate found inside the threshold, the
/// parameters fitted there, and whether that is the walk's `max` (never left).
struct ProfileLimit {
    inside: f64,
    at: [f64; 4],
    reached_max: bool,
}

/// The upper limit of a coordinate whose profile stays within `threshold` of cost: `run`
/// refits the other parameters at a value of the coordinate from a start; `on_inside`
/// sees the parameters of every refit found inside. A cost that is not finite counts as
/// outside. σ's upper limit and η's above its floor are found this way.
fn profile_upper_limit(
    walk: ProfileWalk,
    start: [f64; 4],
    threshold: f64,
    run: impl Fn(f64, &[f64; 4]) -> LmOutcome,
    mut on_inside: impl FnMut(&[f64; 4]),
) -> ProfileLimit {
    let ProfileWalk {
        mut inside,
        first_trial,
        max,
        tolerance,
    } = walk;
    let mut at = start;
    let outside_threshold = |cost: f64| !cost.is_finite() || cost > threshold;
    let mut outside = None;
    let mut trial = first_trial.min(max);
    while inside < max {
        let fitted = run(trial, &at);
        if outside_threshold(fitted.cost) {
            outside = Some(trial);
            break;
        }
        on_inside(&fitted.x);
        (inside, at) = (trial, fitted.x);
        trial = (trial + std::f64::consts::LN_2).min(max);
    }
    let Some(mut outside) = outside else {
        return ProfileLimit {
            inside,
            at,
            reached_max: true,
        };
    };
    while outside - inside > tolerance {
        let mid = 0.5 * (inside + outside);
        let fitted = run(mid, &at);
        if outside_threshold(fitted.cost) {
            outside = mid;
        } else {
            on_inside(&fitted.x);
            (inside, at) = (mid, fitted.x);
        }
    }
    ProfileLimit {
        inside,
        at,
        reached_max: false,
    }
}

/// η at a bound after the arm offset's refits: held there and not fitted. At η → 1,
/// F ∝ (η²−1), so only the amplitude ρs·(η²−1) is determined, not ρs.
pub(super) fn eta_at_bound(state: &mut State) {
    if !state.fitted[RHO_S] {
        return;
    }
    let (lo, hi) = (lower_bounds(), upper_bounds());
    if state.outcome.x[ETA] >= hi[ETA] {
        state.notes.push(Note::EtaAtBound {
            eta: ETA_MAX,
            rho_s_lower: None,
        });
        state.fitted[ETA] = false;
    } else if state.outcome.x[ETA] <= lo[ETA] {
        state.notes.push(Note::EtaAtBound {
            eta: ETA_MIN,
            rho_s_lower: None,
        });
        state.fitted[ETA] = false;
    }
}

/// ρs's lower limit where η is held at its lower bound 1. There ρs = A/(η²−1) is unbounded
/// above, but the readings bound η from above (the Fresnel factor's rise toward grazing is
/// measured): ρs is at least its value at η's 95 % upper limit, the largest η whose
/// profile (the others refitted) stays within χ²(1) at 95 % × `noise_variance` of the fit
/// (the residual variance times the lack-of-fit widening, as the covariance is scaled).
/// Without it the class tree's glossy test (σ < ρs) cannot be made, and a glossy sheet
/// whose η sits at 1 (SG's is 1.02) had no class. The limit is written into the note.
pub(super) fn rho_s_lower_at_eta_floor(
    state: &mut State,
    noise_variance: f64,
    max_iterations: usize,
) {
    if !eta_at_floor_of(&state.notes) || !state.fitted[RHO_S] || !noise_variance.is_finite() {
        return;
    }
    let (problem, best) = (&state.problem, &state.outcome);
    let threshold = best.cost + CHI2_1_95 * noise_variance;
    let mut held = state.fitted.map(|f| !f);
    held[ETA] = true;
    let profile = |ln_excess: f64, start: &[f64; 4]| {
        let mut x = *start;
        x[ETA] = 1.0 + ln_excess.exp();
        levenberg_marquardt(problem, x, held, max_iterations)
    };
    // η − 1 doubled from 0.005 until the profile leaves the threshold, then bisected in
    // ln(η − 1) to about 1 %; ρs the smallest met inside (it falls as η rises).
    let mut rho_s_lower = params_of(&best.x).rho_s;
    profile_upper_limit(
        ProfileWalk {
            inside: (engine::ETA_FLOOR - 1.0).ln(),
            first_trial: 0.005_f64.ln(),
            max: (upper_bounds()[ETA] - 1.0).ln(),
            tolerance: 0.01,
        },
        best.x,
        threshold,
        profile,
        |x| rho_s_lower = rho_s_lower.min(params_of(x).rho_s),
    );
    if !rho_s_lower.is_finite() {
        return;
    }
    for note in state.notes.iter_mut() {
        if let Note::EtaAtBound {
            eta,
            rho_s_lower: lower,
        } = note
            && *eta <= ETA_MIN
        {
            *lower = Some(rho_s_lower);
        }
    }
}

/// The fitted parameters on a bound (and η held at one), and which parameters are free
/// (fitted and off their bounds): the covariance is of those.
pub(super) fn active_bounds(state: &State) -> (Vec<ActiveBound>, [bool; N_PARAMS]) {
    let (lo, hi) = (lower_bounds(), upper_bounds());
    let (x, fitted) = (&state.outcome.x, state.fitted);
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
    for note in &state.notes {
        if let Note::EtaAtBound { eta, .. } = note {
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
    (active_bounds, free)
}
