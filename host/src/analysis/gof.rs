//! Goodness of fit: does the model describe the data?
//!
//! Two tests, each at [`GOF_ALPHA`] = [`STRUCTURE_ALPHA`] = 0.5 %, so that on data the model
//! does describe the flag `lack-of-fit` is raised in at most 1 % of fits (Bonferroni; the
//! campaign in host/tests/it/fit.rs measures the rate):
//!
//! - **χ²** (weighted fits only): χ² = rᵀ Σ⁻¹ r at the optimum, Σ the readings' covariance
//!   (independent noise plus the shared errors), against χ²(ν), ν = n − fitted parameters;
//!   the p-value is the upper tail. Without given uncertainties the noise is estimated from
//!   the residuals, χ²/ν is 1 by construction and there is no χ² test.
//! - **Residual structure** along θr: a model that does not fit leaves runs of same-sign
//!   residuals between neighbouring θr, noise does not. The residuals are first decorrelated
//!   (Σ = L Lᵀ in the order θi, then θr: e = L⁻¹ r, the innovations, independent N(0, 1)
//!   under the model; the shared errors would otherwise correlate neighbours on their own).
//!   Over the pairs (e_j, e_{j+1}) of θr-neighbours at each θi the statistic is the
//!   self-normalised lag-1 sum Z = Σ e_j e_{j+1} / sqrt(Σ (e_j e_{j+1})²), ≈ N(0, 1) under
//!   the model whatever the scale of the noise (so it also works on unweighted fits and is
//!   not fooled by χ² being large); one-sided (structure means positive correlation),
//!   run when there are at least [`STRUCTURE_MIN_PAIRS`] pairs.
use serde::Serialize;
use statrs::distribution::{ChiSquared, ContinuousCDF};

/// Level of the χ² test.
pub const GOF_ALPHA: f64 = 0.005;
/// Level of the residual-structure test.
pub const STRUCTURE_ALPHA: f64 = 0.005;
/// Fewest θr-neighbour pairs for the structure test (fewer: not run).
pub(crate) const STRUCTURE_MIN_PAIRS: usize = 10;

/// Upper tail P(X > χ²) of the chi-square distribution with `dof` degrees of freedom
/// (statrs), `None` without degrees of freedom or for a non-finite χ².
pub(crate) fn chi2_upper_tail(chi2: f64, dof: usize) -> Option<f64> {
    if dof == 0 || !chi2.is_finite() {
        return None;
    }
    let distribution = ChiSquared::new(dof as f64).ok()?;
    Some(distribution.sf(chi2.max(0.0)).clamp(0.0, 1.0))
}

/// Upper tail of χ² when the readings' noise was itself estimated from the data with a
/// relative uncertainty: the weights used were off by a factor e^ε, ε ~ N(0,
/// `scale_log_variance`) (the variance of the log of the estimated noise variance), so
/// that under the model χ² = X·e^−ε with X ~ χ²(`dof`) and P(χ² > c) = E[P(X > c·e^ε)].
/// A sweep's bins have their noise scaled to their own scatter (the session's
/// `scale_bin_noise`); 2,800 bins make χ²/ν's own spread 2.7 % while the scale's is 6 %, and testing against
/// χ²(ν) alone raised the flag in one ideal sweep session in six. 0: exactly
/// [`chi2_upper_tail`].
pub(crate) fn chi2_upper_tail_scaled(
    chi2: f64,
    dof: usize,
    scale_log_variance: f64,
) -> Option<f64> {
    if !(scale_log_variance.is_finite() && scale_log_variance > 0.0) {
        return chi2_upper_tail(chi2, dof);
    }
    if dof == 0 || !chi2.is_finite() {
        return None;
    }
    let distribution = ChiSquared::new(dof as f64).ok()?;
    // Trapezoid rule in u = ε/sd over ±8 sd: the Gaussian weight's tails beyond are
    // below 1e-15, and the integrand is smooth on the scale of the step.
    const STEPS: usize = 320;
    const HALF_WIDTH: f64 = 8.0;
    let sd = scale_log_variance.sqrt();
    let (mut sum, mut weights) = (0.0, 0.0);
    for k in 0..=STEPS {
        let u = -HALF_WIDTH + 2.0 * HALF_WIDTH * k as f64 / STEPS as f64;
        let end = if k == 0 || k == STEPS { 0.5 } else { 1.0 };
        let w = end * (-0.5 * u * u).exp();
        sum += w * distribution.sf(chi2.max(0.0) * (sd * u).exp());
        weights += w;
    }
    Some((sum / weights).clamp(0.0, 1.0))
}

/// The residual-structure test's result.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct StructureTest {
    /// θr-neighbour pairs used.
    pub pairs: usize,
    /// Pooled lag-1 autocorrelation Σ e_j e_{j+1} / Σ e_j² of the decorrelated residuals.
    pub(crate) lag1: f64,
    /// Z = Σ e_j e_{j+1} / sqrt(Σ (e_j e_{j+1})²).
    pub(crate) statistic: f64,
    /// One-sided p-value 1 − Φ(Z).
    pub p_value: f64,
}

/// The structure test on decorrelated residuals `e` given with their θi, in the order θi,
/// then θr (neighbours in θr at the same θi are consecutive). `None` with fewer than
/// [`STRUCTURE_MIN_PAIRS`] pairs or when every residual is 0.
pub(crate) fn structure_test(theta_i_deg: &[f64], e: &[f64]) -> Option<StructureTest> {
    let (mut sum, mut sum_sq, mut pairs) = (0.0, 0.0, 0usize);
    for j in 1..e.len() {
        if theta_i_deg[j] != theta_i_deg[j - 1] {
            continue;
        }
        let product = e[j - 1] * e[j];
        sum += product;
        sum_sq += product * product;
        pairs += 1;
    }
    let energy: f64 = e.iter().map(|v| v * v).sum();
    // (NaN sums fail the tests below as well.)
    if pairs < STRUCTURE_MIN_PAIRS
        || sum_sq.is_nan()
        || sum_sq <= 0.0
        || energy.is_nan()
        || energy <= 0.0
    {
        return None;
    }
    let statistic = sum / sum_sq.sqrt();
    let p_value = 0.5 * libm::erfc(statistic * std::f64::consts::FRAC_1_SQRT_2);
    Some(StructureTest {
        pairs,
        lag1: sum / energy,
        statistic,
        p_value,
    })
}

/// Decorrelated residuals (innovations) of whitened residuals `r` (r_i / std_i) whose
/// covariance is I + S Sᵀ, S the whitened sensitivities (row i = s_i / std_i, `m` columns,
/// row-major): e = L⁻¹ r with L L ᵀ = I + S Sᵀ in the order `order`, computed as the
/// sequential prediction errors of r_i from the earlier readings (a Kalman filter over the
/// shared errors ε ~ N(0, I)), O(n m²). Returned in `order`.
pub(crate) fn innovations(r: &[f64], s: &[f64], m: usize, order: &[usize]) -> Vec<f64> {
    if m == 0 {
        return order.iter().map(|&i| r[i]).collect();
    }
    let mut mean = vec![0.0; m];
    let mut p = vec![0.0; m * m];
    for k in 0..m {
        p[k * m + k] = 1.0;
    }
    let mut v = vec![0.0; m];
    let mut out = Vec::with_capacity(order.len());
    for &i in order {
        let row = &s[i * m..(i + 1) * m];
        for a in 0..m {
            v[a] = (0..m).map(|b| p[a * m + b] * row[b]).sum();
        }
        let variance = 1.0 + row.iter().zip(&v).map(|(x, y)| x * y).sum::<f64>();
        let predicted: f64 = row.iter().zip(&mean).map(|(x, y)| x * y).sum();
        let innovation = r[i] - predicted;
        out.push(innovation / variance.sqrt());
        for a in 0..m {
            mean[a] += v[a] * innovation / variance;
            for b in 0..m {
                p[a * m + b] -= v[a] * v[b] / variance;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chi2_tail_matches_tables() {
        assert!((chi2_upper_tail(3.841_458_820_694_124, 1).unwrap() - 0.05).abs() < 1e-12);
        assert!((chi2_upper_tail(124.342_113_404_2, 100).unwrap() - 0.05).abs() < 1e-9);
        assert_eq!(chi2_upper_tail(1.0, 0), None);
        assert!(chi2_upper_tail(1e7, 280).unwrap() < 1e-300);
    }

    #[test]
    fn an_uncertain_noise_scale_widens_the_chi2_tail_and_none_leaves_it() {
        let dof = 2800;
        for chi2 in [2500.0, 2800.0, 3000.0, 3200.0] {
            assert_eq!(
                chi2_upper_tail_scaled(chi2, dof, 0.0),
                chi2_upper_tail(chi2, dof)
            );
        }
        // χ²/ν = 1.09: far in χ²(ν)'s tail (sd 2.7 %), but 1.4 sd of a 6 % scale.
        let exact = chi2_upper_tail(1.09 * 2800.0, dof).unwrap();
        let scaled = chi2_upper_tail_scaled(1.09 * 2800.0, dof, 0.06_f64.powi(2)).unwrap();
        assert!(
            exact < 1e-3 && scaled > 0.05 && scaled < 0.2,
            "{exact} {scaled}"
        );
        // At the centre the tail stays about a half, and it falls with χ².
        let centre = chi2_upper_tail_scaled(2800.0, dof, 0.0036).unwrap();
        assert!((centre - 0.5).abs() < 0.02, "{centre}");
        let mut last = 1.0;
        for k in 0..40 {
            let p = chi2_upper_tail_scaled(2000.0 + 50.0 * k as f64, dof, 0.0036).unwrap();
            assert!(p <= last + 1e-12);
            last = p;
        }
        assert_eq!(chi2_upper_tail_scaled(f64::NAN, dof, 0.01), None);
        assert_eq!(chi2_upper_tail_scaled(10.0, 0, 0.01), None);
    }

    /// Under the model with a noise scale estimated with a known log-variance, the scaled
    /// tail is uniform: it falls under 0.5 % in about 0.5 % of draws, where the plain χ²
    /// tail falls there far more often.
    #[test]
    fn the_scaled_tail_is_uniform_when_the_scale_is_estimated() {
        use rand::{Rng, SeedableRng};
        use rand_distr::StandardNormal;
        let dof = 2800;
        let log_variance: f64 = 0.06_f64.powi(2);
        let distribution = ChiSquared::new(dof as f64).unwrap();
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        let draws = 4000;
        let (mut scaled_low, mut plain_low) = (0, 0);
        for _ in 0..draws {
            // χ²(ν) as ν + √(2ν)·z is close enough at ν = 2800 for this count.
            let x: f64 =
                rng.sample::<f64, _>(StandardNormal) * (2.0 * dof as f64).sqrt() + dof as f64;
            let epsilon: f64 = rng.sample::<f64, _>(StandardNormal) * log_variance.sqrt();
            let observed = x * (-epsilon).exp();
            scaled_low +=
                usize::from(chi2_upper_tail_scaled(observed, dof, log_variance).unwrap() < 0.005);
            plain_low += usize::from(distribution.sf(observed) < 0.005);
        }
        // 0.5 % of 4000 is 20 (sd 4.5).
        assert!(scaled_low <= 40, "scaled: {scaled_low} of {draws}");
        assert!(plain_low > 200, "plain: {plain_low} of {draws}");
    }

    #[test]
    fn innovations_whiten_a_shared_offset() {
        // r = s·ε + noise with s = 1 for all: the covariance is I + 11ᵀ. Its Cholesky
        // whitening of r = (1, 1, 1) (all the shared offset) is (1/√2, 1/√6, 1/√12).
        let r = [1.0, 1.0, 1.0];
        let s = [1.0, 1.0, 1.0];
        let e = innovations(&r, &s, 1, &[0, 1, 2]);
        let want = [1.0 / 2f64.sqrt(), 1.0 / 6f64.sqrt(), 1.0 / 12f64.sqrt()];
        for (a, b) in e.iter().zip(want) {
            assert!((a - b).abs() < 1e-12, "{e:?}");
        }
    }
}
