//! Small dense linear algebra for the fit's covariance and its shared-error terms: a handful
//! of parameters and a few dozen shared terms, so plain row-major `Vec<f64>` matrices and
//! Cholesky are all that is needed (and keep the fit free of a matrix crate).

/// A square row-major matrix of side `n`.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Square {
    /// Side.
    pub n: usize,
    /// Entries, row-major.
    pub a: Vec<f64>,
}

impl Square {
    /// The n × n zero matrix.
    pub(crate) fn zeros(n: usize) -> Square {
        Square {
            n,
            a: vec![0.0; n * n],
        }
    }

    /// The n × n identity.
    pub fn identity(n: usize) -> Square {
        let mut m = Square::zeros(n);
        for i in 0..n {
            m.a[i * n + i] = 1.0;
        }
        m
    }

    /// Entry (i, j).
    #[inline]
    pub fn at(&self, i: usize, j: usize) -> f64 {
        self.a[i * self.n + j]
    }

    /// Entry (i, j), mutable.
    #[inline]
    pub(crate) fn at_mut(&mut self, i: usize, j: usize) -> &mut f64 {
        &mut self.a[i * self.n + j]
    }
}

/// Lower Cholesky factor of a symmetric positive definite matrix, `None` if it is not
/// (a pivot NaN or ≤ 0).
pub(crate) fn cholesky(m: &Square) -> Option<Square> {
    let n = m.n;
    let mut l = Square::zeros(n);
    for i in 0..n {
        for j in 0..=i {
            let mut s = m.at(i, j);
            for k in 0..j {
                s -= l.at(i, k) * l.at(j, k);
            }
            if i == j {
                if s.is_nan() || s <= 0.0 || s.is_infinite() {
                    return None;
                }
                *l.at_mut(i, i) = s.sqrt();
            } else {
                *l.at_mut(i, j) = s / l.at(j, j);
            }
        }
    }
    Some(l)
}

/// Solve L·x = b in place (L lower triangular).
pub(crate) fn forward_substitute(l: &Square, b: &mut [f64]) {
    for i in 0..l.n {
        let mut s = b[i];
        for k in 0..i {
            s -= l.at(i, k) * b[k];
        }
        b[i] = s / l.at(i, i);
    }
}

/// L⁻¹ of a lower triangular L.
pub(crate) fn lower_inverse(l: &Square) -> Square {
    let n = l.n;
    let mut inv = Square::zeros(n);
    let mut column = vec![0.0; n];
    for c in 0..n {
        column.iter_mut().for_each(|v| *v = 0.0);
        column[c] = 1.0;
        forward_substitute(l, &mut column);
        for r in 0..n {
            *inv.at_mut(r, c) = column[r];
        }
    }
    inv
}

/// Inverse of a symmetric positive definite matrix, scaled to unit diagonal first so that
/// parameters of very different size do not make a well-posed matrix look singular;
/// `None` if it is singular or nearly so (a scaled inverse beyond 1e12).
pub(crate) fn spd_inverse(m: &Square) -> Option<Square> {
    let n = m.n;
    let d: Vec<f64> = (0..n)
        .map(|i| {
            if m.at(i, i) > 0.0 {
                1.0 / m.at(i, i).sqrt()
            } else {
                0.0
            }
        })
        .collect();
    if d.iter().any(|&v| v == 0.0 || !v.is_finite()) {
        return None;
    }
    let mut scaled = Square::zeros(n);
    for i in 0..n {
        for j in 0..n {
            *scaled.at_mut(i, j) = m.at(i, j) * d[i] * d[j];
        }
    }
    let l = cholesky(&scaled)?;
    let li = lower_inverse(&l);
    let mut inv = Square::zeros(n);
    for i in 0..n {
        for j in 0..n {
            // (L Lᵀ)⁻¹ = L⁻ᵀ L⁻¹.
            let s: f64 = (i.max(j)..n).map(|k| li.at(k, i) * li.at(k, j)).sum();
            *inv.at_mut(i, j) = s * d[i] * d[j];
        }
    }
    if (0..n).any(|i| {
        let conditioning = inv.at(i, i) * m.at(i, i);
        conditioning.is_nan() || conditioning >= 1e12
    }) {
        return None;
    }
    Some(inv)
}

/// [`spd_inverse`] of the sub-matrix of an N × N matrix on the indices in `free`, the
/// other rows and columns 0 (the fit's parameters, some held; the adaptive design's, with
/// the σ slope): `None` if that is singular.
pub(crate) fn spd_inverse_free<const N: usize>(
    m: &[[f64; N]; N],
    free: &[bool; N],
) -> Option<[[f64; N]; N]> {
    let index: Vec<usize> = (0..N).filter(|&i| free[i]).collect();
    let mut sub = Square::zeros(index.len());
    for (a, &i) in index.iter().enumerate() {
        for (b, &j) in index.iter().enumerate() {
            *sub.at_mut(a, b) = m[i][j];
        }
    }
    let inverse = spd_inverse(&sub)?;
    let mut out = [[0.0; N]; N];
    for (a, &i) in index.iter().enumerate() {
        for (b, &j) in index.iter().enumerate() {
            out[i][j] = inverse.at(a, b);
        }
    }
    Some(out)
}

/// The weighted least-squares line y = a + b·x held to a, b ≥ 0 (a variance has no
/// negative part): with a negative slope the weighted mean alone, with a negative
/// intercept the line through the origin.
pub(crate) fn nonnegative_line(x: &[f64], y: &[f64], w: &[f64]) -> Option<(f64, f64)> {
    let (mut s1, mut sx, mut sxx, mut sy, mut sxy) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for ((&x, &y), &w) in x.iter().zip(y).zip(w) {
        s1 += w;
        sx += w * x;
        sxx += w * x * x;
        sy += w * y;
        sxy += w * x * y;
    }
    let det = s1 * sxx - sx * sx;
    let (a, b) = if det > 0.0 {
        ((sy * sxx - sx * sxy) / det, (s1 * sxy - sx * sy) / det)
    } else {
        (sy / s1, 0.0)
    };
    let (a, b) = if b < 0.0 {
        (sy / s1, 0.0)
    } else if a < 0.0 {
        (0.0, sxy / sxx)
    } else {
        (a, b)
    };
    (a.is_finite() && b.is_finite() && a + b > 0.0).then_some((a, b))
}

/// One step of the iterated estimate of each reading's noise variance var = a + b·f², f
/// its fitted value (a detector's floor and its part proportional to the signal), shared
/// by the arm-offset test and the extension's term tests on readings without
/// uncertainties. Each squared residual is divided by 1 − h, h its leverage (at most 20×:
/// below 1 − h = 0.05 a residual says too little of its reading's noise), since a glossy
/// peak's few readings pull the fit to themselves and their residuals understate their
/// noise; the line is fitted with the gamma quasi-likelihood's weights 1/var² of the
/// `previous` step's variances (a squared residual's variance is 2·var²), so that the
/// peak's large residuals do not set the floor; no variance is below 10⁻⁶ of the mean
/// squared residual. `None` when the residuals say nothing (all zero, or not finite).
pub(crate) fn variance_step(
    fitted: &[f64],
    residuals: &[f64],
    leverages: &[f64],
    previous: &[f64],
) -> Option<Vec<f64>> {
    let r2: Vec<f64> = residuals
        .iter()
        .zip(leverages)
        .map(|(r, h)| r * r / (1.0 - h).max(0.05))
        .collect();
    let mean_r2 = r2.iter().sum::<f64>() / r2.len().max(1) as f64;
    if !(mean_r2.is_finite() && mean_r2 > 0.0) {
        return None;
    }
    // Only the weights' ratios matter: the previous variances scaled to a mean of 1 keep
    // 1/var² finite.
    let mean_previous = previous.iter().sum::<f64>() / previous.len().max(1) as f64;
    if !(mean_previous.is_finite() && mean_previous > 0.0) {
        return None;
    }
    let w: Vec<f64> = previous
        .iter()
        .map(|v| (v / mean_previous).powi(-2))
        .collect();
    let f2: Vec<f64> = fitted.iter().map(|f| f * f).collect();
    let (a, b) = nonnegative_line(&f2, &r2, &w).unwrap_or((mean_r2, 0.0));
    let floor = 1e-6 * mean_r2;
    Some(f2.iter().map(|f| (a + b * f).max(floor)).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inverse_of_a_badly_scaled_matrix() {
        // Parameters of size 1e-3 and 1e3 with a correlation of 0.9.
        let s = [1e-3, 1.0, 1e3];
        let mut m = Square::zeros(3);
        let r = [[1.0, 0.9, 0.2], [0.9, 1.0, 0.3], [0.2, 0.3, 1.0]];
        for i in 0..3 {
            for j in 0..3 {
                *m.at_mut(i, j) = r[i][j] / (s[i] * s[j]);
            }
        }
        let inv = spd_inverse(&m).expect("positive definite");
        for i in 0..3 {
            for j in 0..3 {
                let p: f64 = (0..3).map(|k| m.at(i, k) * inv.at(k, j)).sum();
                assert!(
                    (p - if i == j { 1.0 } else { 0.0 }).abs() < 1e-9,
                    "({i},{j}) {p}"
                );
            }
        }
        let mut singular = Square::zeros(2);
        singular.a = vec![1.0, 1.0, 1.0, 1.0];
        assert!(spd_inverse(&singular).is_none());
    }
}
