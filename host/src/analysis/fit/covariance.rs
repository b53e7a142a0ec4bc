//! The last step: goodness of fit on the final model, the widening it calls for, and the
//! parameters' covariance C = G Σ Gᵀ (G the estimator's linearised map) with its budget
//! and the 95 % intervals.
//!
//! Why last: every step before it can change the model (a parameter taken out, an arm
//! offset fitted, the arm zero's uncertainty added to the shared errors), and the
//! covariance is of the model as it finally stands. The goodness of fit comes first
//! within it, since a misfit widens the covariance (the module docs of [`super`]).
use super::arm_offset::ArmTest;
use super::engine::{self, LeastSquaresProblem};
use super::result::{forget_uncertainty, not_identified_of};
use super::validation::geometry_order;
use super::{
    ArmOffset, BudgetTerm, ETA_MAX, ETA_MIN, FitOptions, N_PARAMS, Note, Observation,
    SIGMA_MAX_DEG, SIGMA_MIN_DEG, SharedError, State, t_quantile_975,
};
use crate::analysis::gof::{self, StructureTest};
use crate::analysis::linalg::{self, Square};
use crate::analysis::model::{ETA, PARAM_NAMES, RHO_S, SIGMA};

/// Standard normal quantile at 0.975.
pub(super) const Z_975: f64 = 1.959_963_984_540_054;
/// Largest lag-1 autocorrelation used in the widening factor.
const WIDENING_MAX_LAG1: f64 = 0.9;

/// What the goodness of fit found, and the residuals and Jacobian it was found at.
pub(super) struct Goodness {
    /// Whitened residuals per reading.
    residuals: Vec<f64>,
    /// Whitened gradients per reading in x = (ln σ, A, ρd, η).
    jacobian: Vec<[f64; 4]>,
    /// The cost, weighted fits only.
    pub chi2: Option<f64>,
    /// χ²'s upper-tail p-value.
    pub gof_p: Option<f64>,
    /// The residual variance the covariance is scaled by (1 weighted).
    pub s2: f64,
    /// Without uncertainties, one reading's standard deviation from the residuals.
    pub noise_from_residuals: Option<f64>,
    /// The residual-structure test.
    pub structure: Option<StructureTest>,
    /// The model does not describe the data.
    pub lack_of_fit: bool,
    /// The widening factor k (1 unless `lack_of_fit`).
    pub variance_scale: f64,
}

/// The χ² test (weighted) or the noise estimated from the residuals, the structure test
/// on the residuals decorrelated in θ order, and the widening they call for.
pub(super) fn goodness_of_fit(
    state: &mut State,
    observations: &[Observation],
    x: &[f64; 4],
    cost: f64,
    dof: usize,
    options: &FitOptions,
) -> Goodness {
    let (problem, notes) = (&state.problem, &mut state.notes);
    let (residuals, jacobian) = problem.rows(x);
    let (chi2, gof_p, s2, noise_from_residuals) = if problem.weighted {
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
    let order = geometry_order(observations);
    let decorrelated = gof::innovations(&residuals, &problem.shared.s, problem.shared.m, &order);
    let theta_i_sorted: Vec<f64> = order.iter().map(|&i| observations[i].theta_i_deg).collect();
    let structure = gof::structure_test(&theta_i_sorted, &decorrelated);
    let lack_of_fit = gof_p.is_some_and(|p| p < gof::GOF_ALPHA)
        || structure.is_some_and(|s| s.p_value < gof::STRUCTURE_ALPHA);
    if gof_p.is_none() && structure.is_none() && dof > 0 {
        notes.push(Note::FitNotTestable);
    }
    let variance_scale = widening(lack_of_fit, chi2, structure, dof, notes);
    Goodness {
        residuals,
        jacobian,
        chi2,
        gof_p,
        s2,
        noise_from_residuals,
        structure,
        lack_of_fit,
        variance_scale,
    }
}

/// The covariance's factor under lack of fit: the Birge ratio times the variance inflation
/// of the residuals' lag-1 autocorrelation (the module docs of [`super`]), 1 otherwise.
fn widening(
    lack_of_fit: bool,
    chi2: Option<f64>,
    structure: Option<StructureTest>,
    dof: usize,
    notes: &mut Vec<Note>,
) -> f64 {
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
    variance_scale
}

/// The parameters' uncertainty: covariance, intervals, budget and the arm offset's.
pub(super) struct Uncertainty {
    /// Of (σ, ρs, ρd, η), zero where not identified.
    pub covariance: [[f64; N_PARAMS]; N_PARAMS],
    /// 95 % intervals, clipped to the bounds.
    pub ci95: [Option<(f64, f64)>; N_PARAMS],
    /// Whether each interval was clipped.
    pub(crate) ci_clipped: [bool; N_PARAMS],
    /// The covariance's diagonal by source.
    pub budget: Vec<BudgetTerm>,
    /// The fitted arm offset with its interval.
    pub arm_offset: Option<ArmOffset>,
}

/// Covariance C = G Σ Gᵀ over the free parameters in x = (ln σ, A, ρd, η) and δ0, split
/// into the independent noise's share and each shared error's ([`split_covariance`]), then
/// taken to (σ, ρs, ρd, η) with the intervals ([`natural_uncertainty`]).
pub(super) fn parameters(
    state: &mut State,
    goodness: &Goodness,
    free: [bool; N_PARAMS],
    arm: &ArmTest,
    dof: usize,
) -> Uncertainty {
    let x = state.outcome.x;
    let problem = &state.problem;
    let free_index: Vec<usize> = (0..4).filter(|&i| free[i]).collect();
    let mut columns: Vec<Vec<f64>> = free_index
        .iter()
        .map(|&i| goodness.jacobian.iter().map(|row| row[i]).collect())
        .collect();
    if arm.fitted {
        columns.push(problem.shift_column(&x));
    }
    let mut uncertainty = Uncertainty {
        covariance: [[0.0; 4]; 4],
        ci95: [None; 4],
        ci_clipped: [false; 4],
        budget: Vec::new(),
        arm_offset: None,
    };
    let split = if dof == 0 {
        state.notes.push(Note::NoDegreesOfFreedom);
        None
    } else if !columns.is_empty() {
        let split = split_covariance(problem, &state.shared, &columns, goodness, dof);
        if split.is_none() {
            state.notes.push(Note::SingularJacobian);
        }
        split
    } else {
        None
    };
    if let Some((terms_x, total)) = &split {
        let to_natural = ToNatural::new(&x, &free_index, columns.len());
        natural_uncertainty(
            state,
            &mut uncertainty,
            &to_natural,
            terms_x,
            total,
            goodness,
            free,
            arm,
            dof,
        );
    } else if arm.fitted {
        let lr = arm.statistic.unwrap_or(f64::NAN);
        let deg = state.problem.shift_deg;
        uncertainty.arm_offset = Some(ArmOffset {
            deg,
            std_deg: f64::NAN,
            ci95: (f64::NAN, f64::NAN),
            lr,
        });
        state.notes.push(Note::ArmOffsetFitted {
            deg,
            std_deg: f64::NAN,
            lr,
        });
    }
    uncertainty
}

/// The covariance in x of the `columns` (whitened Jacobian columns) by source, and in all:
/// H⁻¹ of the GLS normal equations less each shared term's share G s_k (G s_k)ᵀ is the
/// independent noise's (estimated from the residuals without uncertainties: the sandwich
/// from [`SANDWICH_MIN_DOF`], s²·H⁻¹ below), plus `lack of fit` when widened. `None`
/// when H is singular.
#[allow(clippy::type_complexity)]
fn split_covariance(
    problem: &LeastSquaresProblem,
    shared: &[SharedError],
    columns: &[Vec<f64>],
    goodness: &Goodness,
    dof: usize,
) -> Option<(Vec<(String, Square)>, Square)> {
    let (weighted, s2, variance_scale) = (problem.weighted, goodness.s2, goodness.variance_scale);
    let p = columns.len();
    let normal = gls_normal(&problem.shared, columns, None);
    let h_inv = linalg::spd_inverse(&normal.h)?;
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
            sandwich(&h_inv, columns, &goodness.residuals),
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
    let mut terms_x: Vec<(String, Square)> = Vec::new();
    terms_x.push((noise_name.to_string(), noise));
    terms_x.extend(shared_terms);
    if variance_scale > 1.0 {
        terms_x.push((
            "lack of fit".to_string(),
            scale(total.clone(), (variance_scale - 1.0) / variance_scale),
        ));
    }
    Some((terms_x, total))
}

/// The map from a covariance in the fit's x = (ln σ, A, ρd, η) over the free parameters
/// (and δ0 last, when fitted) to one in (σ, ρs, ρd, η).
struct ToNatural {
    /// Per column of the covariance, d(σ, ρs, ρd, η)/d(that parameter).
    jac: Vec<[f64; 4]>,
}

impl ToNatural {
    /// d(σ, ρs, ρd, η)/d(ln σ, A, ρd, η): σ = e^x0, ρs = A/(η²−1); δ0 enters none.
    fn new(x: &[f64; 4], free_index: &[usize], p: usize) -> ToNatural {
        let k = engine::eta_factor(x[3]);
        let mut jac_full = [[0.0; 4]; 4];
        jac_full[0][0] = x[0].exp();
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
        ToNatural { jac }
    }

    /// J S Jᵀ.
    fn of(&self, s: &Square) -> [[f64; 4]; 4] {
        let (jac, p) = (&self.jac, self.jac.len());
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
    }
}

/// The covariance, budget and 95 % intervals in (σ, ρs, ρd, η) from the split covariance
/// in x, with what is not identified zeroed (ρs too when η's interval reaches 1, where it
/// is unbounded), and the arm offset's interval.
#[allow(clippy::too_many_arguments)]
fn natural_uncertainty(
    state: &mut State,
    out: &mut Uncertainty,
    to_natural: &ToNatural,
    terms_x: &[(String, Square)],
    total: &Square,
    goodness: &Goodness,
    free: [bool; N_PARAMS],
    arm: &ArmTest,
    dof: usize,
) {
    let x = state.outcome.x;
    let params = engine::params_of(&x);
    let p = to_natural.jac.len();
    let quantile = if state.problem.weighted && goodness.variance_scale == 1.0 {
        Z_975
    } else {
        t_quantile_975(dof)
    };
    let full = to_natural.of(total);
    // ρs = A/(η²−1) is unbounded above when η's interval reaches 1: then it is not
    // identified, and only bounded below (by its value at η's upper limit).
    if free[ETA] && free[RHO_S] {
        let se_eta = full[ETA][ETA].max(0.0).sqrt();
        if x[ETA] - quantile * se_eta <= engine::ETA_FLOOR {
            let eta_hi = (x[ETA] + quantile * se_eta).min(ETA_MAX);
            state.notes.push(Note::RhoSUnbounded {
                rho_s_lower: x[RHO_S] / engine::eta_factor(eta_hi),
            });
        }
    }
    let not_identified = not_identified_of(&state.notes);
    let unknown: Vec<usize> = (0..4)
        .filter(|&i| not_identified.iter().any(|u| u.param == PARAM_NAMES[i]))
        .collect();
    out.covariance = full;
    for (name, term) in terms_x {
        let natural = to_natural.of(term);
        out.budget.push(BudgetTerm {
            name: name.clone(),
            variance: std::array::from_fn(|i| natural[i][i]),
        });
    }
    for &i in &unknown {
        forget_uncertainty(&mut out.covariance, &mut out.budget, i);
    }
    let free_index: Vec<usize> = (0..4).filter(|&i| free[i]).collect();
    for &i in &free_index {
        if unknown.contains(&i) {
            continue;
        }
        let v = params.to_array()[i];
        let sd = out.covariance[i][i].max(0.0).sqrt();
        let (interval, clipped) = interval_95(i, v, sd, quantile);
        out.ci_clipped[i] = clipped;
        out.ci95[i] = Some(interval);
    }
    if arm.fitted {
        let se = total.at(p - 1, p - 1).max(0.0).sqrt();
        let deg = state.problem.shift_deg;
        let lr = arm.statistic.unwrap_or(f64::NAN);
        out.arm_offset = Some(ArmOffset {
            deg,
            std_deg: se,
            ci95: (deg - quantile * se, deg + quantile * se),
            lr,
        });
        state.notes.push(Note::ArmOffsetFitted {
            deg,
            std_deg: se,
            lr,
        });
    }
}

/// The 95 % interval of σ, ρs, ρd or η (by index) from its estimate, standard deviation and
/// quantile, within the parameter's range, and whether the range clipped it. σ's and ρs's
/// are taken in their logarithms (dln x = dx/x), so they stay positive and follow the
/// scale their uncertainty has: σ's is the lobe's relative width, ρs = A/(η² − 1) is a
/// ratio. The base fit and the extensions' members take theirs here alike.
pub(crate) fn interval_95(index: usize, value: f64, sd: f64, quantile: f64) -> ((f64, f64), bool) {
    let natural_lo = [SIGMA_MIN_DEG, 0.0, 0.0, ETA_MIN];
    let natural_hi = [SIGMA_MAX_DEG, f64::INFINITY, f64::INFINITY, ETA_MAX];
    let (low, high) = if (index == SIGMA || index == RHO_S) && value > 0.0 {
        let relative = sd / value;
        (
            value * (-quantile * relative).exp(),
            value * (quantile * relative).exp(),
        )
    } else {
        (value - quantile * sd, value + quantile * sd)
    };
    let (lo, hi) = (low.max(natural_lo[index]), high.min(natural_hi[index]));
    ((lo, hi), lo != low || hi != high)
}

/// The normal equations of whitened columns X (p × n, each a column of the Jacobian
/// divided by the std) in the Σ⁻¹ metric: H = XᵀΣ⁻¹X, b = XᵀΣ⁻¹r (when `r` is given), and
/// P' = L⁻¹ S̃ᵀ X (m × p) for the shared terms' shares.
pub(super) struct Normal {
    pub h: Square,
    pub b: Vec<f64>,
    pub(crate) pl: Vec<Vec<f64>>,
}

pub(super) fn gls_normal(
    shared: &engine::Shared,
    columns: &[Vec<f64>],
    r: Option<&[f64]>,
) -> Normal {
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
            let mut column: Vec<f64> = pl.iter().map(|row| row[c]).collect();
            linalg::forward_substitute(&shared.l, &mut column);
            for (row, v) in pl.iter_mut().zip(column) {
                row[c] = v;
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
pub(super) const SANDWICH_MIN_DOF: usize = 20;

/// HC3 sandwich H⁻¹ (Σ_i x_i x_iᵀ r_i² / (1 − h_ii)²) H⁻¹, h_ii = x_iᵀ H⁻¹ x_i the
/// leverage (clamped to 0.99), for unweighted columns X and residuals r.
pub(super) fn sandwich(h_inv: &Square, columns: &[Vec<f64>], residuals: &[f64]) -> Square {
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
