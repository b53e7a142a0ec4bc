//! Gross errors among the readings, and too few degrees of freedom to judge a fit: the
//! steps that keep `gonio fit` honest on a table without uncertainties, where the noise is
//! scaled to the residuals and no χ² test can ever fire.
//!
//! **The outlier test** is the mean-shift test of each reading (is reading i better
//! described by the model plus a shift of its own?), Bonferroni over the n readings at
//! [`OUTLIER_ALPHA`] per data set (unweighted) or [`OUTLIER_ALPHA_WEIGHTED`] (weighted):
//! - *with uncertainties* the statistic is the GLS one with the readings' covariance Σ
//!   known, t_i = (Σ⁻¹r)_i / √P_ii, P = Σ⁻¹ − Σ⁻¹X H⁻¹XᵀΣ⁻¹ (X the Jacobian of the free
//!   parameters, H = XᵀΣ⁻¹X), normal under the model; divided by √max(1, median t²/0.455),
//!   a robust Birge ratio, so that stated uncertainties a little too small (or a model a
//!   little off) do not make every large reading an outlier, while one gross error cannot
//!   move the median. The level is lower than the unweighted one: sessions fit their
//!   readings many times, and a gross error there is also a χ² misfit (lack-of-fit) already.
//! - *without uncertainties* the readings are weighted equally but their noise is not
//!   equal (a photometer's has a floor and a part proportional to the reading: G's peak
//!   readings are 70 times noisier than its diffuse ones), so each reading's residual is
//!   set against the variance the least-squares residual has under the noise model
//!   v(f) = A + B·f² (f the fitted value): Var r_j = A·(1 − h_jj) + B·d_j with
//!   d_j = f_j²(1 − 2h_jj) + x_jᵀH⁻¹(Σ_k x_k x_kᵀ f_k²)H⁻¹x_j (h the hat matrix), which are
//!   moment equations for A, B ≥ 0 in the squared residuals (fitted as a gamma
//!   quasi-likelihood, weights 1/Var²). A and B are estimated *without* the reading tested
//!   (and without readings already found), so a gross error cannot inflate its own scale
//!   (externally studentized); the reference is Student t on ν − 2. A reading whose fitted
//!   value is more than twice every other's (the glossy peak of a sparse table) has no
//!   other reading to judge its noise by: it is set against the estimate with itself in,
//!   which a gross error there inflates (such an error is seen only through the misfit it
//!   leaves elsewhere).
//!
//! Readings found are named in the notes ([`Note::Outlier`]) with the flag
//! [`Flag::Outlier`]. More than [`max_outliers`] readings beyond the critical value are not
//! gross errors of single readings but a model that does not describe the data: that is
//! the goodness of fit's business, and no reading is named.
//!
//! **Too few degrees of freedom**: below [`MIN_DOF_UNWEIGHTED`] without uncertainties (the
//! noise is estimated from ν residuals; Student t on ν has no finite variance for ν ≤ 2,
//! so the parameters' uncertainty region the class confidence samples is not described by
//! a covariance; and the outlier test, which estimates a two-term noise, has no residual
//! left to test with) and at ν = 0 with them (no residual at all, no covariance), the fit
//! is flagged [`Flag::FewDegreesOfFreedom`] and the class confidence is capped or withheld
//! ([`crate::analysis::classify`]).
use super::engine::{LeastSquaresProblem, global_fit, lower_bounds, upper_bounds};
use super::{FitResult, N_PARAMS, Note, Observation};
use crate::analysis::flags::Flag;
use crate::analysis::linalg::{self, Square};
use statrs::distribution::{ContinuousCDF, Normal, StudentsT};

/// Family-wise false-alarm rate of the outlier test per data set without uncertainties.
pub const OUTLIER_ALPHA: f64 = 0.01;
/// The same with uncertainties (a session's fits).
pub const OUTLIER_ALPHA_WEIGHTED: f64 = 0.001;
/// Smallest ν of a fit without uncertainties that is judged: see the module docs.
pub const MIN_DOF_UNWEIGHTED: usize = 3;
/// Median of χ²(1): the robust Birge ratio's reference.
const CHI2_1_MEDIAN: f64 = 0.454_936_423_119_572_7;
/// A fitted value this many times every other's (in variance, 2² in value) is an
/// extrapolation of the noise model: see the module docs.
const EXTRAPOLATION: f64 = 4.0;
/// Readings from which a table's nearly interpolated readings are also tested left out
/// ([`most_extreme`]).
const LEAVE_OUT_MIN_READINGS: usize = 30;
/// The largest readings tested left out.
const LEAVE_OUT_LARGEST: usize = 2;
/// How much beyond the critical value a reading tested left out must be: the prediction's
/// linearised variance underestimates on the peak (6.1 standard deviations seen on a clean
/// Strategy 2 table of SG against a critical 4.1).
const LEAVE_OUT_STRICTER: f64 = 2.0;
/// Iterations of the noise model's quasi-likelihood fit.
const NOISE_MODEL_ITERATIONS: usize = 8;

/// Most readings named as gross errors in one data set: beyond it the residuals are the
/// model's misfit, not single bad readings.
pub fn max_outliers(n: usize) -> usize {
    (n / 50).max(3)
}

/// A reading the test found.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Found {
    index: usize,
    fitted: f64,
    standardized: f64,
}

/// What the screen found: the readings taken for gross errors, and the critical value.
#[derive(Clone, Debug, PartialEq, Default)]
pub(super) struct Screen {
    found: Vec<Found>,
    critical: f64,
    few_dof: Option<usize>,
}

/// Run the outlier test on the fit `x` of `problem` (the free parameters' columns, the arm
/// offset's when fitted) and check the degrees of freedom.
pub(super) fn screen(
    problem: &LeastSquaresProblem,
    observations: &[Observation],
    x: &[f64; 4],
    free: [bool; N_PARAMS],
    arm_fitted: bool,
    dof: usize,
    max_iterations: usize,
) -> Screen {
    let weighted = problem.weighted;
    let min_dof = if weighted { 1 } else { MIN_DOF_UNWEIGHTED };
    let mut out = Screen {
        few_dof: (dof < min_dof).then_some(dof),
        ..Screen::default()
    };
    if out.few_dof.is_some() {
        return out;
    }
    let n = observations.len();
    let mut columns = free_columns(problem, x, free);
    if arm_fitted {
        columns.push(problem.shift_column(x));
    }
    let found = if weighted {
        out.critical = critical_value(n, 0, true);
        gls_statistics(problem, &problem.rows(x).0, &columns).map_or_else(Vec::new, |t| {
            let values = problem.values(x);
            (0..n)
                .filter(|&i| t[i].abs() > out.critical)
                .map(|index| Found {
                    index,
                    fitted: values[index],
                    standardized: -t[index],
                })
                .collect()
        })
    } else {
        let Some(reference_dof) = n.checked_sub(columns.len() + 2).filter(|&d| d >= 1) else {
            return out;
        };
        out.critical = critical_value(n, reference_dof, false);
        let first = Fitted {
            problem,
            refit: None,
            x: *x,
            columns,
            index: (0..n).collect(),
        };
        let mut found = one_at_a_time(first, observations, out.critical, max_iterations);
        found.truncate(max_outliers(n));
        found
    };
    if found.len() <= max_outliers(n) {
        out.found = found;
    }
    out
}

/// A fit the unweighted test looks at: its problem (on the readings `index` of the input),
/// its parameters and the whitened Jacobian's columns of its free parameters.
struct Fitted<'a> {
    /// The fit's own problem (on the readings `index`), or the fit's when on all.
    problem: &'a LeastSquaresProblem,
    refit: Option<LeastSquaresProblem>,
    x: [f64; 4],
    columns: Vec<Vec<f64>>,
    index: Vec<usize>,
}

impl Fitted<'_> {
    fn problem(&self) -> &LeastSquaresProblem {
        self.refit.as_ref().unwrap_or(self.problem)
    }
}

/// The columns of the parameters fitted and off their bounds at `x`.
fn free_columns(
    problem: &LeastSquaresProblem,
    x: &[f64; 4],
    free: [bool; N_PARAMS],
) -> Vec<Vec<f64>> {
    let jacobian = problem.rows(x).1;
    (0..N_PARAMS)
        .filter(|&k| free[k])
        .map(|k| jacobian.iter().map(|row| row[k]).collect())
        .collect()
}

/// Without uncertainties: the most extreme reading of the fit is tested ([`most_extreme`]);
/// when it is beyond `critical` it is named and the model fitted again without it, and so
/// on, one at a time, until none is beyond or more than [`max_outliers`] were named (the
/// first [`max_outliers`] are named: the most extreme first, so that a misfit of the model
/// after a gross error does not hide the error).
fn one_at_a_time(
    first: Fitted,
    observations: &[Observation],
    critical: f64,
    max_iterations: usize,
) -> Vec<Found> {
    let n = observations.len();
    let mut found: Vec<Found> = Vec::new();
    let mut current = first;
    while found.len() <= max_outliers(n) {
        let Some(candidate) = most_extreme(&current, observations, max_iterations) else {
            break;
        };
        if candidate.t.abs() <= critical {
            break;
        }
        found.push(Found {
            index: candidate.index,
            fitted: candidate.predicted,
            standardized: -candidate.t,
        });
        current = match candidate.without {
            Some(without) => without,
            None => without(&current, candidate.index, observations, max_iterations),
        };
    }
    found
}

/// The most extreme reading of a fit, judged by the fit without it.
struct Candidate<'a> {
    /// Its index in the input.
    index: usize,
    /// (prediction − reading) over its standard deviation (the fit's residual's sign).
    t: f64,
    /// The value the fit without it predicts there.
    predicted: f64,
    /// The fit without it, when it was made.
    without: Option<Fitted<'a>>,
}

/// The reading of `fit` least like the others: the largest |t| in the fit ([`external`]),
/// and on tables of at least [`LEAVE_OUT_MIN_READINGS`] the [`LEAVE_OUT_LARGEST`] largest
/// readings (a gross error upwards the nonlinear fit may have chased, as a ×1000 reading on
/// a glossy flank that got a spike of its own, σ → 0 and an arm offset, and a residual of
/// 0), each left out and predicted by the fit of the others, t [`LEAVE_OUT_STRICTER`]
/// times stricter:
/// t = (y_i − f₍ᵢ₎) / √(v(f₍ᵢ₎) + Var f₍ᵢ₎), the noise model v of the others' residuals and
/// the prediction's variance under it (the externally studentized prediction residual).
/// On short tables the prediction from a leave-one-out fit is too nonlinear for its
/// linearised variance (11 false alarms in 288 clean tables with it on every candidate,
/// none without). `None` without enough readings.
fn most_extreme<'a>(
    fit: &Fitted<'a>,
    observations: &[Observation],
    max_iterations: usize,
) -> Option<Candidate<'a>> {
    let problem = fit.problem();
    let (residuals, _) = problem.rows(&fit.x);
    let n = residuals.len();
    n.checked_sub(fit.columns.len() + 3).filter(|&d| d >= 1)?;
    let values = problem.values(&fit.x);
    let squares: Vec<f64> = residuals.iter().map(|r| r * r).collect();
    let excluded = vec![false; n];
    // A singular fit (a gross error fitted with a spike of its own) has no in-fit
    // statistics; its largest readings are still tested left out.
    let (k, t) = variance_terms(&fit.columns, &values)
        .and_then(|(c, d)| {
            (0..n)
                .map(|i| (i, external(i, &residuals, &squares, &c, &d, &excluded)))
                .max_by(|a, b| a.1.abs().total_cmp(&b.1.abs()))
        })
        .unwrap_or((0, 0.0));
    let mut best = Candidate {
        index: fit.index[k],
        t,
        predicted: values[k],
        without: None,
    };
    if n >= LEAVE_OUT_MIN_READINGS {
        let mut by_value: Vec<usize> = (0..n).collect();
        by_value.sort_by(|&a, &b| {
            let (ya, yb) = (observations[fit.index[a]], observations[fit.index[b]]);
            yb.radiance_factor.total_cmp(&ya.radiance_factor)
        });
        for i in by_value.into_iter().take(LEAVE_OUT_LARGEST) {
            if let Some(mut candidate) = left_out(fit, i, observations, max_iterations) {
                candidate.t /= LEAVE_OUT_STRICTER;
                if candidate.t.abs() > best.t.abs() {
                    best = candidate;
                }
            }
        }
    }
    Some(best)
}

/// The fit of `fit`'s readings but the input's reading `index`.
fn without<'a>(
    fit: &Fitted<'a>,
    index: usize,
    observations: &[Observation],
    max_iterations: usize,
) -> Fitted<'a> {
    let problem = fit.problem();
    let kept: Vec<usize> = fit.index.iter().copied().filter(|&i| i != index).collect();
    let subset: Vec<Observation> = kept.iter().map(|&i| observations[i]).collect();
    // Without the arm offset the first fit found: a gross error can call for one (a
    // spike fitted onto a flank), and the others are judged without it.
    let refit = LeastSquaresProblem::new(&subset, &[], problem.response, 0.0);
    let x = global_fit(&refit, max_iterations).x;
    let (lo, hi) = (lower_bounds(), upper_bounds());
    let free: [bool; N_PARAMS] = std::array::from_fn(|p| x[p] > lo[p] && x[p] < hi[p]);
    Fitted {
        problem: fit.problem,
        columns: free_columns(&refit, &x, free),
        refit: Some(refit),
        x,
        index: kept,
    }
}

/// Reading `k` of `fit` left out: the fit of the others and its prediction there.
fn left_out<'a>(
    fit: &Fitted<'a>,
    k: usize,
    observations: &[Observation],
    max_iterations: usize,
) -> Option<Candidate<'a>> {
    let index = fit.index[k];
    let others = without(fit, index, observations, max_iterations);
    let (refit, x) = (others.problem(), others.x);
    let (lo, hi) = (lower_bounds(), upper_bounds());
    let free: [bool; N_PARAMS] = std::array::from_fn(|p| x[p] > lo[p] && x[p] < hi[p]);
    let columns = &others.columns;
    let (residuals, _) = refit.rows(&x);
    let values = refit.values(&x);
    let (c, d) = variance_terms(columns, &values)?;
    let squares: Vec<f64> = residuals.iter().map(|r| r * r).collect();
    let (a, b) = noise_model(&squares, &c, &d, &vec![true; squares.len()]);
    // The prediction and its gradient at the reading left out, on its own one-reading problem.
    let alone = LeastSquaresProblem::new(&[observations[index]], &[], refit.response, 0.0);
    let (r, jacobian) = alone.rows(&x);
    let predicted = observations[index].radiance_factor + r[0];
    let g: Vec<f64> = (0..N_PARAMS)
        .filter(|&p| free[p])
        .map(|p| jacobian[0][p])
        .collect();
    let spread = prediction_variance(columns, &values, &g, a, b)?;
    let variance = a + b * predicted * predicted + spread;
    let t = if variance > 0.0 && variance.is_finite() {
        r[0] / variance.sqrt()
    } else {
        0.0
    };
    Some(Candidate {
        index,
        t,
        predicted,
        without: Some(others),
    })
}

/// gᵀ H⁻¹ (Σ_k x_k x_kᵀ v_k) H⁻¹ g, v_k = a + b f_k²: the variance of the least-squares
/// prediction with gradient g under the noise model.
fn prediction_variance(
    columns: &[Vec<f64>],
    values: &[f64],
    g: &[f64],
    a: f64,
    b: f64,
) -> Option<f64> {
    let p = columns.len();
    if p == 0 {
        return Some(0.0);
    }
    let mut h = Square::zeros(p);
    let mut meat = Square::zeros(p);
    for i in 0..p {
        for j in 0..p {
            let (mut hs, mut ms) = (0.0, 0.0);
            for (k, f) in values.iter().enumerate() {
                let xx = columns[i][k] * columns[j][k];
                hs += xx;
                ms += xx * (a + b * f * f);
            }
            *h.at_mut(i, j) = hs;
            *meat.at_mut(i, j) = ms;
        }
    }
    let h_inv = linalg::spd_inverse(&h)?;
    let u: Vec<f64> = (0..p)
        .map(|i| (0..p).map(|j| h_inv.at(i, j) * g[j]).sum())
        .collect();
    Some(
        (0..p)
            .map(|i| (0..p).map(|j| u[i] * meat.at(i, j) * u[j]).sum::<f64>())
            .sum(),
    )
}

/// The Bonferroni critical value of |t| over `n` readings: normal with uncertainties,
/// Student t on `reference_dof` without.
fn critical_value(n: usize, reference_dof: usize, weighted: bool) -> f64 {
    let alpha = if weighted {
        OUTLIER_ALPHA_WEIGHTED
    } else {
        OUTLIER_ALPHA
    };
    let p = 1.0 - alpha / (2.0 * n.max(1) as f64);
    if weighted {
        Normal::new(0.0, 1.0).map_or(f64::INFINITY, |d| d.inverse_cdf(p))
    } else {
        StudentsT::new(0.0, 1.0, reference_dof.max(1) as f64)
            .map_or(f64::INFINITY, |d| d.inverse_cdf(p))
    }
}

/// Add the screen's findings to the result: a note per reading found and per shortfall of
/// degrees of freedom, and their flags.
pub(super) fn record(result: &mut FitResult, screen: &Screen, observations: &[Observation]) {
    if let Some(dof) = screen.few_dof {
        let min_dof = if result.weighted {
            1
        } else {
            MIN_DOF_UNWEIGHTED
        };
        result
            .notes
            .push(Note::FewDegreesOfFreedom { dof, min_dof });
        result.flags.push(Flag::FewDegreesOfFreedom);
    }
    for f in &screen.found {
        let o = &observations[f.index];
        result.notes.push(Note::Outlier {
            line: None,
            index: f.index,
            theta_i_deg: o.theta_i_deg,
            theta_r_deg: o.theta_r_deg,
            value: o.radiance_factor,
            fitted: f.fitted,
            standardized: f.standardized,
            critical: screen.critical,
            alpha: if result.weighted {
                OUTLIER_ALPHA_WEIGHTED
            } else {
                OUTLIER_ALPHA
            },
        });
    }
    if !screen.found.is_empty() {
        result.flags.push(Flag::Outlier);
    }
    result.flags.sort();
    result.flags.dedup();
}

/// With the readings' covariance known: the GLS mean-shift statistic of every reading
/// (module docs), scaled by the robust Birge ratio. `None` when H is singular.
fn gls_statistics(
    problem: &LeastSquaresProblem,
    residuals: &[f64],
    columns: &[Vec<f64>],
) -> Option<Vec<f64>> {
    let n = residuals.len();
    let shared = &problem.shared;
    let m = shared.m;
    let l_inv = linalg::lower_inverse(&shared.l);
    // Σ̃⁻¹v = v − S̃ M⁻¹ S̃ᵀ v, M⁻¹ = L⁻ᵀL⁻¹ (Woodbury on the whitened covariance I + S̃S̃ᵀ).
    let apply = |v: &[f64]| -> Vec<f64> {
        if m == 0 {
            return v.to_vec();
        }
        let mut a = vec![0.0; m];
        for (i, vi) in v.iter().enumerate() {
            for (k, s) in shared.row(i).iter().enumerate() {
                a[k] += s * vi;
            }
        }
        let b: Vec<f64> = (0..m)
            .map(|r| (0..=r).map(|c| l_inv.at(r, c) * a[c]).sum())
            .collect();
        let c: Vec<f64> = (0..m)
            .map(|r| (r..m).map(|q| l_inv.at(q, r) * b[q]).sum())
            .collect();
        v.iter()
            .enumerate()
            .map(|(i, vi)| {
                vi - shared
                    .row(i)
                    .iter()
                    .zip(&c)
                    .map(|(s, c)| s * c)
                    .sum::<f64>()
            })
            .collect()
    };
    let u = apply(residuals);
    let z: Vec<Vec<f64>> = columns.iter().map(|c| apply(c)).collect();
    let p = columns.len();
    let mut h = Square::zeros(p);
    for a in 0..p {
        for b in 0..p {
            *h.at_mut(a, b) = columns[a].iter().zip(&z[b]).map(|(x, z)| x * z).sum();
        }
    }
    let h_inv = if p > 0 { linalg::spd_inverse(&h)? } else { h };
    let mut t = Vec::with_capacity(n);
    for i in 0..n {
        let whitened: f64 = (0..m)
            .map(|r| {
                let e: f64 = (0..=r).map(|c| l_inv.at(r, c) * shared.row(i)[c]).sum();
                e * e
            })
            .sum();
        let zi: Vec<f64> = z.iter().map(|col| col[i]).collect();
        let lever: f64 = (0..p)
            .map(|a| (0..p).map(|b| zi[a] * h_inv.at(a, b) * zi[b]).sum::<f64>())
            .sum();
        let pii = 1.0 - whitened - lever;
        t.push(if pii > 1e-12 { u[i] / pii.sqrt() } else { 0.0 });
    }
    let mut squares: Vec<f64> = t.iter().map(|v| v * v).collect();
    squares.sort_by(f64::total_cmp);
    let birge = (squares[n / 2] / CHI2_1_MEDIAN).max(1.0);
    Some(t.iter().map(|v| v / birge.sqrt()).collect())
}

/// The ingredients of each residual's variance under v(f) = A + B f²: (1 − h_jj, d_j).
fn variance_terms(columns: &[Vec<f64>], values: &[f64]) -> Option<(Vec<f64>, Vec<f64>)> {
    let n = values.len();
    let p = columns.len();
    let mut h = Square::zeros(p);
    let mut q = Square::zeros(p);
    for a in 0..p {
        for b in 0..p {
            let (mut hs, mut qs) = (0.0, 0.0);
            for k in 0..n {
                let xx = columns[a][k] * columns[b][k];
                hs += xx;
                qs += xx * values[k] * values[k];
            }
            *h.at_mut(a, b) = hs;
            *q.at_mut(a, b) = qs;
        }
    }
    let h_inv = if p > 0 { linalg::spd_inverse(&h)? } else { h };
    // G = H⁻¹ Q H⁻¹.
    let mut hq = Square::zeros(p);
    for a in 0..p {
        for b in 0..p {
            *hq.at_mut(a, b) = (0..p).map(|c| h_inv.at(a, c) * q.at(c, b)).sum();
        }
    }
    let mut g = Square::zeros(p);
    for a in 0..p {
        for b in 0..p {
            *g.at_mut(a, b) = (0..p).map(|c| hq.at(a, c) * h_inv.at(c, b)).sum();
        }
    }
    let quad = |m: &Square, j: usize| -> f64 {
        (0..p)
            .map(|a| {
                (0..p)
                    .map(|b| columns[a][j] * m.at(a, b) * columns[b][j])
                    .sum::<f64>()
            })
            .sum()
    };
    let mut c = Vec::with_capacity(n);
    let mut d = Vec::with_capacity(n);
    for j in 0..n {
        let hjj = quad(&h_inv, j).clamp(0.0, 1.0);
        c.push(1.0 - hjj);
        d.push((values[j] * values[j] * (1.0 - 2.0 * hjj) + quad(&g, j)).max(0.0));
    }
    Some((c, d))
}

/// A, B ≥ 0 of the noise model from the squared residuals of the readings `used`: the
/// gamma quasi-likelihood (weights 1/μ², μ_j = A c_j + B d_j), iterated from equal weights.
fn noise_model(squares: &[f64], c: &[f64], d: &[f64], used: &[bool]) -> (f64, f64) {
    let mut mu: Vec<f64> = vec![1.0; squares.len()];
    let (mut a, mut b) = (0.0, 0.0);
    for _ in 0..NOISE_MODEL_ITERATIONS {
        let (mut scc, mut scd, mut sdd, mut sce, mut sde) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for j in 0..squares.len() {
            if !used[j] {
                continue;
            }
            let w = 1.0 / (mu[j] * mu[j]).max(1e-300);
            scc += w * c[j] * c[j];
            scd += w * c[j] * d[j];
            sdd += w * d[j] * d[j];
            sce += w * c[j] * squares[j];
            sde += w * d[j] * squares[j];
        }
        let det = scc * sdd - scd * scd;
        (a, b) = if det > 1e-12 * scc * sdd && det > 0.0 {
            ((sce * sdd - sde * scd) / det, (sde * scc - sce * scd) / det)
        } else {
            (-1.0, -1.0)
        };
        if a < 0.0 || b < 0.0 {
            // On the boundary: the better of A alone and B alone.
            let a_only = if scc > 0.0 { sce / scc } else { 0.0 };
            let b_only = if sdd > 0.0 { sde / sdd } else { 0.0 };
            let loss = |a: f64, b: f64| -> f64 {
                (0..squares.len())
                    .filter(|&j| used[j])
                    .map(|j| {
                        let w = 1.0 / (mu[j] * mu[j]).max(1e-300);
                        w * (squares[j] - a * c[j] - b * d[j]).powi(2)
                    })
                    .sum()
            };
            (a, b) = if loss(a_only.max(0.0), 0.0) <= loss(0.0, b_only.max(0.0)) {
                (a_only.max(0.0), 0.0)
            } else {
                (0.0, b_only.max(0.0))
            };
        }
        for j in 0..squares.len() {
            mu[j] = a * c[j] + b * d[j];
        }
        let floor = mu.iter().copied().fold(0.0_f64, f64::max) * 1e-12;
        mu.iter_mut().for_each(|v| *v = v.max(floor));
    }
    (a, b)
}

/// Reading i's residual over its standard deviation under the noise model of the other
/// readings not `excluded` (with itself when its fitted value is beyond the others': an
/// extrapolation, module docs).
fn external(
    i: usize,
    residuals: &[f64],
    squares: &[f64],
    c: &[f64],
    d: &[f64],
    excluded: &[bool],
) -> f64 {
    let n = residuals.len();
    let others_d = (0..n)
        .filter(|&j| j != i && !excluded[j])
        .map(|j| d[j])
        .fold(0.0_f64, f64::max);
    let mut used: Vec<bool> = excluded.iter().map(|e| !e).collect();
    if d[i] <= EXTRAPOLATION * others_d {
        used[i] = false;
    }
    let (a, b) = noise_model(squares, c, d, &used);
    let variance = a * c[i] + b * d[i];
    if variance > 0.0 && variance.is_finite() {
        residuals[i] / variance.sqrt()
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::classify::REFERENCES;
    use crate::analysis::fit::{FitOptions, fit};
    use crate::analysis::model::{self, Params};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn pairs(s: &protocol::schedules::Schedule) -> Vec<(f64, f64)> {
        s.iter()
            .map(|g| (g.theta_i.deg(), g.theta_r.deg()))
            .collect()
    }

    /// The schedules of the method: Strategy 1 at M = 12, Strategy 2 at δ = 2°, the
    /// 284-geometry grid.
    fn schedules() -> Vec<(&'static str, Vec<(f64, f64)>)> {
        use protocol::schedules as s;
        vec![
            (
                "strategy 1, M = 12",
                pairs(&s::strategy1(12).expect("M = 12")),
            ),
            (
                "strategy 2, δ = 2°",
                pairs(&s::strategy2(2).expect("δ = 2")),
            ),
            ("284 geometries", pairs(&s::full_grid())),
        ]
    }

    /// Exact TSL readings through the default 1° window with noise of 1 % of the reading
    /// and 0.003 absolute (the issue's), without uncertainties.
    fn table(p: &Params, geometries: &[(f64, f64)], seed: u64) -> Vec<Observation> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let acceptance = Some(model::DEFAULT_ACCEPTANCE_DEG);
        geometries
            .iter()
            .map(|&(ti, tr)| {
                let f = model::evaluate_reading(p, ti, tr, 0.0, acceptance).0;
                let std = (0.01 * f).hypot(0.003);
                let u1: f64 = 1.0 - rng.random::<f64>();
                let u2: f64 = rng.random::<f64>();
                let z = (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos();
                Observation {
                    theta_i_deg: ti,
                    theta_r_deg: tr,
                    radiance_factor: (f + std * z).max(0.0),
                    std: None,
                    theta_r_span_deg: 0.0,
                }
            })
            .collect()
    }

    /// The test's false alarms on clean exact-TSL tables without uncertainties: the eight
    /// papers on three schedules, 12 seeds each (288 tables), at most 1 % stated; none seen.
    #[test]
    fn few_false_alarms_on_clean_tables() {
        let mut flagged = Vec::new();
        let mut total = 0;
        for (name, g) in schedules() {
            for (k, r) in REFERENCES.iter().enumerate() {
                for seed in 0..12u64 {
                    let obs = table(&r.params, &g, 1000 * k as u64 + seed);
                    let f = fit(&obs, &FitOptions::default()).expect("a valid table");
                    total += 1;
                    if f.flags.contains(&Flag::Outlier) {
                        flagged.push(format!("{name} {} seed {seed}: {:?}", r.name, f.notes));
                    }
                }
            }
        }
        assert_eq!(total, 288);
        // 1 % of 288 is 2.9: at most 2 (the stated rate with margin).
        assert!(
            flagged.len() <= 2,
            "{} of {total}: {flagged:#?}",
            flagged.len()
        );
    }

    /// One reading ×1000 of G is named wherever it is not on the lobe of a short table:
    /// all 51 positions on Strategy 2, 10 of 12 on Strategy 1 (the two at θi 60° are the
    /// peak itself, whose noise no other reading shows, and the reading beside it), 280 of
    /// 284 on the grid (every 4th position tried here). Where it is not named the class
    /// confidence is below 0.95 or the result flagged. The same with the model's
    /// extensions: a term that bends to the reading does not explain it (on Strategy 2
    /// an off-specular peak 13° out or σ varying with θi took 4 of the 51 before the
    /// explanation had to be a prediction, `extension::outliers_explained`).
    #[test]
    fn a_reading_times_1000_is_named() {
        for extensions in [false, true] {
            times_1000_named(&FitOptions {
                extensions,
                ..FitOptions::default()
            });
        }
    }

    fn times_1000_named(options: &FitOptions) {
        use crate::analysis::classify::classify;
        for (name, g) in schedules() {
            let clean = table(&REFERENCES[0].params, &g, 7);
            let step = if clean.len() > 100 { 4 } else { 1 };
            let (mut found, mut tried) = (0, 0);
            for i in (0..clean.len()).step_by(step) {
                let mut obs = clean.clone();
                obs[i].radiance_factor *= 1000.0;
                let f = fit(&obs, options).expect("a valid table");
                tried += 1;
                let named = f.notes.iter().any(|n| {
                    matches!(n, Note::Outlier { index, standardized, .. } if *index == i && *standardized > 0.0)
                });
                found += usize::from(named);
                let c = classify(&f);
                assert!(
                    !f.flags.is_empty() || c.confidence < 0.95,
                    "{name}, reading {i} ×1000: unflagged at confidence {}",
                    c.confidence
                );
            }
            let needed = match clean.len() {
                12 => 10,
                51 => 51,
                _ => tried - 2,
            };
            assert!(
                found >= needed,
                "{name}, extensions {}: {found} of {tried} named",
                options.extensions
            );
        }
    }

    /// A table with as many readings as parameters gives no class (before: a class at
    /// confidence 1.00); with one or two residuals and no uncertainties the class's
    /// confidence stays below 0.95; both are flagged few-degrees-of-freedom.
    #[test]
    fn too_few_degrees_of_freedom_give_no_confident_class() {
        use crate::analysis::classify::classify;
        let all = [
            (20.0, 0.0),
            (20.0, 20.0),
            (45.0, 45.0),
            (60.0, 60.0),
            (60.0, 30.0),
            (30.0, 30.0),
            (45.0, 10.0),
        ];
        for (n, expect_class) in [(4, false), (5, true)] {
            let obs = table(&REFERENCES[0].params, &all[..n], 3);
            let f = fit(&obs, &FitOptions::default()).expect("a valid table");
            assert!(f.dof < MIN_DOF_UNWEIGHTED, "{n}: ν {}", f.dof);
            assert!(
                f.flags.contains(&Flag::FewDegreesOfFreedom),
                "{n}: {:?}",
                f.flags
            );
            assert!(
                f.notes
                    .iter()
                    .any(|n| matches!(n, Note::FewDegreesOfFreedom { .. }))
            );
            let c = classify(&f);
            assert!(c.confidence < 0.95, "{n}: {c:?}");
            if !expect_class && f.dof == 0 {
                assert!(c.class.is_none() && c.undecided.is_some(), "{n}: {c:?}");
            }
        }
        // With uncertainties only ν = 0 is too few.
        let mut obs = table(&REFERENCES[0].params, &all[..4], 3);
        obs.iter_mut()
            .for_each(|o| o.std = Some(0.01 * o.radiance_factor + 0.003));
        let f = fit(&obs, &FitOptions::default()).expect("a valid table");
        assert_eq!(
            f.flags.contains(&Flag::FewDegreesOfFreedom),
            f.dof == 0,
            "ν {}",
            f.dof
        );
        assert!(f.dof > 0 || classify(&f).class.is_none());
    }
}
