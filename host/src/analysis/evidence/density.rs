//! The normal densities and small matrices the likelihood ratio is made of, over the
//! compared parameters only (σ, ρs, ρd or the subset both sheets determined).
use crate::analysis::linalg::{self, Square};

/// A stored 3 × 3 covariance (σ, ρs, ρd in log space).
pub(crate) type Cov3 = [[f64; 3]; 3];

/// The rows and columns of `m` for `params` (indices into σ, ρs, ρd).
pub(crate) fn restrict(m: &Cov3, params: &[usize]) -> Square {
    let mut s = Square::zeros(params.len());
    for (r, &i) in params.iter().enumerate() {
        for (c, &j) in params.iter().enumerate() {
            *s.at_mut(r, c) = m[i][j];
        }
    }
    s
}

pub(crate) fn add(a: &Square, b: &Square) -> Square {
    Square {
        n: a.n,
        a: a.a.iter().zip(&b.a).map(|(x, y)| x + y).collect(),
    }
}

pub(crate) fn scale(a: &Square, f: f64) -> Square {
    Square {
        n: a.n,
        a: a.a.iter().map(|x| x * f).collect(),
    }
}

pub(crate) fn add3(a: &Cov3, b: &Cov3) -> Cov3 {
    std::array::from_fn(|r| std::array::from_fn(|c| a[r][c] + b[r][c]))
}

pub(crate) fn scale3(a: &Cov3, f: f64) -> Cov3 {
    a.map(|row| row.map(|v| v * f))
}

/// The covariance with the same correlations as `shape` and the given variances: D R D,
/// positive semi-definite whenever `shape` is (a variance of 0 gives zero rows).
pub(crate) fn with_variances(shape: &Cov3, variances: [f64; 3]) -> Cov3 {
    let sd = variances.map(|v| v.max(0.0).sqrt());
    std::array::from_fn(|r| {
        std::array::from_fn(|c| {
            if r == c {
                variances[r].max(0.0)
            } else {
                let norm = (shape[r][r] * shape[c][c]).sqrt();
                let rho = if norm > 0.0 { shape[r][c] / norm } else { 0.0 };
                rho.clamp(-1.0, 1.0) * sd[r] * sd[c]
            }
        })
    })
}

/// The smallest pivot of a correlation matrix's Cholesky factor (1 − R² of a parameter
/// on those before it) that counts as positive definite: below it the correlations are
/// ±1 but for rounding.
const MIN_CORRELATION_PIVOT: f64 = 1e-6;

/// `c` if it is positive definite, else its variances alone: a scatter of fewer rows than
/// parameters (three spots of one sheet: two degrees of freedom for three parameters) is
/// singular through its correlations, which so few rows cannot show anyway. Judged on the
/// correlations with a margin ([`MIN_CORRELATION_PIVOT`]): a singular scatter can pass a
/// Cholesky factorisation by rounding and then fail the next one, of a sum of it (the
/// schema test's library at seed 4121 could make no population).
pub(crate) fn positive_definite_or_diagonal(c: Cov3) -> Cov3 {
    let variances = diagonal_of(&c);
    let diagonal =
        std::array::from_fn(|r| std::array::from_fn(|k| if r == k { c[r][r] } else { 0.0 }));
    if variances.iter().any(|v| !(v.is_finite() && *v > 0.0)) {
        return diagonal;
    }
    let correlation: Cov3 = std::array::from_fn(|r| {
        std::array::from_fn(|k| c[r][k] / (variances[r] * variances[k]).sqrt())
    });
    match linalg::cholesky(&restrict(&correlation, &[0, 1, 2])) {
        Some(l) if (0..3).all(|i| l.at(i, i).powi(2) >= MIN_CORRELATION_PIVOT) => c,
        _ => diagonal,
    }
}

fn diagonal_of(c: &Cov3) -> [f64; 3] {
    std::array::from_fn(|i| c[i][i])
}

/// Scatter of `rows` about `mean`, divided by `dof` (at least 1).
pub(crate) fn scatter<'a>(
    rows: impl Iterator<Item = &'a [f64; 3]>,
    mean: &[f64; 3],
    dof: usize,
) -> Cov3 {
    let mut s = [[0.0; 3]; 3];
    for row in rows {
        for r in 0..3 {
            for c in 0..3 {
                s[r][c] += (row[r] - mean[r]) * (row[c] - mean[c]);
            }
        }
    }
    scale3(&s, 1.0 / dof.max(1) as f64)
}

/// ln N(x; mean, cov) by Cholesky; `None` when cov is not positive definite.
pub(crate) fn log_normal_density(x: &[f64], mean: &[f64], cov: &Square) -> Option<f64> {
    let quad = mahalanobis_squared(x, mean, cov)?;
    let l = linalg::cholesky(cov)?;
    let log_det: f64 = (0..l.n).map(|i| 2.0 * l.at(i, i).ln()).sum();
    Some(-0.5 * (x.len() as f64 * (2.0 * std::f64::consts::PI).ln() + log_det + quad))
}

/// (x − mean)ᵀ cov⁻¹ (x − mean); `None` when cov is not positive definite.
pub(crate) fn mahalanobis_squared(x: &[f64], mean: &[f64], cov: &Square) -> Option<f64> {
    let l = linalg::cholesky(cov)?;
    let mut w: Vec<f64> = x.iter().zip(mean).map(|(a, b)| a - b).collect();
    linalg::forward_substitute(&l, &mut w);
    Some(w.iter().map(|v| v * v).sum())
}

/// A covariance over the compared parameters (at most three), on the stack: the densities
/// of a search or a validation are evaluated once per stock of the population, and a heap
/// matrix per evaluation made memory allocation a third of their time (issue 29).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Small {
    /// How many parameters (1 to 3).
    pub(crate) n: usize,
    /// Its entries; those beyond `n` are zero.
    pub(crate) a: Cov3,
}

impl Small {
    /// The rows and columns of `m` for `params` (as [`restrict`]).
    pub(crate) fn restrict(m: &Cov3, params: &[usize]) -> Small {
        let mut a = [[0.0; 3]; 3];
        for (r, &i) in params.iter().enumerate() {
            for (c, &j) in params.iter().enumerate() {
                a[r][c] = m[i][j];
            }
        }
        Small { n: params.len(), a }
    }

    /// Of a heap matrix of at most three rows.
    pub(crate) fn of(m: &Square) -> Small {
        let mut a = [[0.0; 3]; 3];
        for (r, row) in a.iter_mut().enumerate().take(m.n) {
            for (c, v) in row.iter_mut().enumerate().take(m.n) {
                *v = m.at(r, c);
            }
        }
        Small { n: m.n, a }
    }

    /// The sum, entry by entry.
    pub(crate) fn plus(&self, other: &Small) -> Small {
        Small {
            n: self.n,
            a: add3(&self.a, &other.a),
        }
    }

    /// Its Cholesky factor with the log determinant, by the same operations in the same
    /// order as [`linalg::cholesky`] (so the same numbers); `None` when not positive
    /// definite.
    pub(crate) fn factor(&self) -> Option<Factor> {
        let n = self.n;
        let mut l = [[0.0; 3]; 3];
        for i in 0..n {
            for j in 0..=i {
                let mut s = self.a[i][j];
                for k in 0..j {
                    s -= l[i][k] * l[j][k];
                }
                if i == j {
                    if s.is_nan() || s <= 0.0 || s.is_infinite() {
                        return None;
                    }
                    l[i][i] = s.sqrt();
                } else {
                    l[i][j] = s / l[j][j];
                }
            }
        }
        let log_det: f64 = (0..n).map(|i| 2.0 * l[i][i].ln()).sum();
        Some(Factor { n, l, log_det })
    }
}

/// A covariance's Cholesky factor L (lower) and ln det, for densities of many points.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Factor {
    n: usize,
    l: Cov3,
    log_det: f64,
}

impl Factor {
    /// (x − mean)ᵀ cov⁻¹ (x − mean), as [`mahalanobis_squared`] computes it.
    pub(crate) fn mahalanobis_squared(&self, x: &[f64; 3], mean: &[f64; 3]) -> f64 {
        let mut w = [0.0; 3];
        for ((w, x), m) in w.iter_mut().zip(x).zip(mean).take(self.n) {
            *w = x - m;
        }
        for i in 0..self.n {
            let mut s = w[i];
            for k in 0..i {
                s -= self.l[i][k] * w[k];
            }
            w[i] = s / self.l[i][i];
        }
        w[..self.n].iter().map(|v| v * v).sum()
    }

    /// ln N(x; mean, cov) given the squared Mahalanobis distance, as
    /// [`log_normal_density`] computes it.
    pub(crate) fn log_density_at(&self, distance_squared: f64) -> f64 {
        -0.5 * (self.n as f64 * (2.0 * std::f64::consts::PI).ln() + self.log_det + distance_squared)
    }

    /// ln N(x; mean, cov).
    pub(crate) fn log_density(&self, x: &[f64; 3], mean: &[f64; 3]) -> f64 {
        self.log_density_at(self.mahalanobis_squared(x, mean))
    }
}

/// The entries of `v` for `params`, on the stack (those beyond are zero).
pub(crate) fn pick3(v: &[f64; 3], params: &[usize]) -> [f64; 3] {
    let mut out = [0.0; 3];
    for (k, &i) in params.iter().enumerate() {
        out[k] = v[i];
    }
    out
}

/// The first (at most three) entries of `v`, on the stack.
pub(crate) fn to3(v: &[f64]) -> [f64; 3] {
    let mut out = [0.0; 3];
    for (o, x) in out.iter_mut().zip(v) {
        *o = *x;
    }
    out
}

/// ln of the mean of exp(values), without overflow.
pub(crate) fn log_mean_exp(values: &[f64]) -> f64 {
    let max = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if !max.is_finite() {
        return max;
    }
    max + (values.iter().map(|v| (v - max).exp()).sum::<f64>() / values.len() as f64).ln()
}

/// The one-sided 95 % upper confidence bound of a variance estimated with `dof` degrees of
/// freedom (normal data): s²·ν / χ²₀.₀₅(ν). Infinite for ν = 0.
pub(crate) fn upper_variance(variance: f64, dof: usize) -> f64 {
    use statrs::distribution::{ChiSquared, ContinuousCDF};
    if dof == 0 {
        return f64::INFINITY;
    }
    match ChiSquared::new(dof as f64) {
        Ok(chi) => variance * dof as f64 / chi.inverse_cdf(0.05),
        Err(_) => f64::INFINITY,
    }
}

/// The upper-tail probability of a χ² statistic with `dof` degrees of freedom.
pub(crate) fn chi_squared_tail(statistic: f64, dof: usize) -> f64 {
    use statrs::distribution::{ChiSquared, ContinuousCDF};
    match ChiSquared::new(dof.max(1) as f64) {
        Ok(chi) => chi.sf(statistic.max(0.0)),
        Err(_) => f64::NAN,
    }
}

/// The χ² quantile with `dof` degrees of freedom at probability `p`.
pub(crate) fn chi_squared_quantile(p: f64, dof: usize) -> f64 {
    use statrs::distribution::{ChiSquared, ContinuousCDF};
    match ChiSquared::new(dof.max(1) as f64) {
        Ok(chi) => chi.inverse_cdf(p),
        Err(_) => f64::NAN,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_variance_bound_is_above_the_estimate_and_closes_in_with_dof() {
        let b3 = upper_variance(1.0, 3);
        let b30 = upper_variance(1.0, 30);
        let b300 = upper_variance(1.0, 300);
        assert!(b3 > b30 && b30 > b300 && b300 > 1.0, "{b3} {b30} {b300}");
        // χ²₀.₀₅(3) = 0.3518: 3 / 0.3518.
        assert!((b3 - 8.527).abs() < 0.01, "{b3}");
        assert_eq!(upper_variance(1.0, 0), f64::INFINITY);
    }

    #[test]
    fn a_singular_scatter_is_its_variances_alone_however_it_rounds() {
        // Three spots of one sheet (seed 4121 of the schema test), their scatter scaled to
        // its upper bound: rank 2, yet its Cholesky factorisation passed by rounding, and
        // that of twice it (spot and sheet levels) did not.
        let estimate = [
            [
                5.710668786450433e-7,
                8.243802567137047e-6,
                -1.2112128448741914e-7,
            ],
            [
                8.243802567137047e-6,
                0.0010101701120949257,
                -8.001354587084331e-6,
            ],
            [
                -1.2112128448741914e-7,
                -8.001354587084331e-6,
                6.956281412352244e-8,
            ],
        ];
        let upper = with_variances(&estimate, diagonal_of(&estimate).map(|v| 19.496 * v));
        let used = positive_definite_or_diagonal(upper);
        assert_eq!(used[0][1], 0.0, "{used:?}");
        assert_eq!(diagonal_of(&used), diagonal_of(&upper));
        let within: Cov3 = std::array::from_fn(|r| std::array::from_fn(|c| 2.0 * used[r][c]));
        assert!(linalg::cholesky(&restrict(&within, &[0, 1, 2])).is_some());
        // A scatter that is positive definite stays as it is.
        let fine = [[4.0, 1.0, 0.5], [1.0, 2.0, 0.2], [0.5, 0.2, 1.0]];
        assert_eq!(positive_definite_or_diagonal(fine), fine);
    }

    #[test]
    fn with_variances_keeps_the_correlation() {
        let shape = [[4.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let c = with_variances(&shape, [1.0, 4.0, 0.0]);
        assert!((c[0][1] - 0.5 * 1.0 * 2.0).abs() < 1e-12);
        assert_eq!(c[2], [0.0, 0.0, 0.0]);
    }
}
