//! Goodness of fit: does the model describe the data?
//!
//! Two tests, each at [`GOF_ALPHA`] = [`STRUCTURE_ALPHA`] = 0.5 %, so that on data the model
//! does describe the flag `lack-of-fit` is raised in at most 1 % of fits (Bonferroni; the
//! campaign in host/tests/fit.rs measures the rate):
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
pub const STRUCTURE_MIN_PAIRS: usize = 10;

/// Upper tail P(X > χ²) of the chi-square distribution with `dof` degrees of freedom
/// (statrs), `None` without degrees of freedom or for a non-finite χ².
pub fn chi2_upper_tail(chi2: f64, dof: usize) -> Option<f64> {
    if dof == 0 || !chi2.is_finite() {
        return None;
    }
    let distribution = ChiSquared::new(dof as f64).ok()?;
    Some(distribution.sf(chi2.max(0.0)).clamp(0.0, 1.0))
}

/// The residual-structure test's result.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct StructureTest {
    /// θr-neighbour pairs used.
    pub pairs: usize,
    /// Pooled lag-1 autocorrelation Σ e_j e_{j+1} / Σ e_j² of the decorrelated residuals.
    pub lag1: f64,
    /// Z = Σ e_j e_{j+1} / sqrt(Σ (e_j e_{j+1})²).
    pub statistic: f64,
    /// One-sided p-value 1 − Φ(Z).
    pub p_value: f64,
}

/// The structure test on decorrelated residuals `e` given with their θi, in the order θi,
/// then θr (neighbours in θr at the same θi are consecutive). `None` with fewer than
/// [`STRUCTURE_MIN_PAIRS`] pairs or when every residual is 0.
pub fn structure_test(theta_i_deg: &[f64], e: &[f64]) -> Option<StructureTest> {
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
    if pairs < STRUCTURE_MIN_PAIRS || sum_sq.is_nan() || sum_sq <= 0.0 || energy.is_nan() || energy <= 0.0 {
        return None;
    }
    let statistic = sum / sum_sq.sqrt();
    let p_value = 0.5 * libm::erfc(statistic * std::f64::consts::FRAC_1_SQRT_2);
    Some(StructureTest { pairs, lag1: sum / energy, statistic, p_value })
}

/// Decorrelated residuals (innovations) of whitened residuals `r` (r_i / std_i) whose
/// covariance is I + S Sᵀ, S the whitened sensitivities (row i = s_i / std_i, `m` columns,
/// row-major): e = L⁻¹ r with L L ᵀ = I + S Sᵀ in the order `order`, computed as the
/// sequential prediction errors of r_i from the earlier readings (a Kalman filter over the
/// shared errors ε ~ N(0, I)), O(n m²). Returned in `order`.
pub fn innovations(r: &[f64], s: &[f64], m: usize, order: &[usize]) -> Vec<f64> {
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
