//! The forensic question: could two measured sheets be the same paper stock?
//!
//! Each sheet's session gives TSL parameters with their covariance. The test statistic is
//! the Mahalanobis distance of the parameter difference under the sum of the two
//! covariances (the sheets are measured independently), over the parameters both sessions
//! determined. Under "same stock" (and the fits' Gaussian approximation) its square is
//! chi-square with k degrees of freedom, k the number of parameters compared; the sheets
//! are distinguishable when p < α (default 0.01). Sheets of different classes are
//! distinguishable whatever p says: the class is itself a measured property of the stock.
//! Only what both sessions determined is used: a parameter reported as null (not
//! identified, with its reason in the session) or with zero variance is left out, and an
//! undecided class (null) never makes two sheets "different classes".
//!
//! σ, ρs and ρd are compared in log space: they are positive scale parameters whose
//! uncertainty is multiplicative (σ's interval is asymmetric, ρs runs from 0.1 to 60
//! across papers), so a difference in log is a relative difference and its covariance
//! follows by the delta method, Cov(ln x_i, ln x_j) = Cov(x_i, x_j) / (x_i x_j). η is
//! bounded (1…3), not a scale, and stays linear. A parameter at or below 0 in either
//! sheet is compared linearly.
use crate::analysis::fit::N_PARAMS;
use crate::analysis::model::{ETA, PARAM_NAMES};
use serde::Serialize;
use serde_json::Value;
use std::path::{Path, PathBuf};
use thiserror::Error;

/// Default significance level: p below it means distinguishable. 1 % keeps false
/// "different stock" findings rare, which is the costly error in a forensic comparison.
pub const DEFAULT_ALPHA: f64 = 0.01;

/// Parameter names with units, in covariance order, for tables.
pub const PARAM_LABELS: [&str; N_PARAMS] = ["sigma [deg]", "rho_s", "rho_d", "eta"];

/// Why a session result cannot be read. Every variant names the file; key errors name the key.
#[derive(Debug, Error)]
pub enum CompareError {
    /// The file cannot be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The file is not JSON.
    #[error("{path}: not valid JSON: {message}")]
    Json {
        /// The file.
        path: PathBuf,
        /// The parser's message.
        message: String,
    },
    /// A key the comparison needs is absent.
    #[error("{path}: missing key `{key}`")]
    MissingKey {
        /// The file.
        path: PathBuf,
        /// Dotted path of the key, e.g. `result.covariance`.
        key: String,
    },
    /// A key holds the wrong kind of value.
    #[error("{path}: key `{key}` must be {expected}")]
    BadValue {
        /// The file.
        path: PathBuf,
        /// Dotted path of the key.
        key: String,
        /// What it should hold.
        expected: &'static str,
    },
}

/// What the comparison reads from one `session.json`.
#[derive(Clone, Debug, PartialEq)]
pub struct SessionResult {
    /// The file read.
    pub file: PathBuf,
    /// Sample name.
    pub sample: String,
    /// Class as the session spelled it (G, SG, rough-I…); `None` when the session could not
    /// decide it (null in the file).
    pub class: Option<String>,
    /// σ [deg], ρs, ρd, η; `None` where the session reported null (not determined).
    pub values: [Option<f64>; 4],
    /// Covariance of (σ [deg], ρs, ρd, η); rows/columns of parameters not fitted are 0.
    pub covariance: [[f64; 4]; 4],
}

impl SessionResult {
    /// The sheet it measured, as the evidence weighs it: one spot (σ, ρs, ρd and their
    /// covariance; a parameter the session left null stays undetermined).
    pub fn sheet(&self) -> crate::analysis::evidence::Sheet {
        let values = std::array::from_fn(|i| self.values[i]);
        let covariance = std::array::from_fn(|r| std::array::from_fn(|c| self.covariance[r][c]));
        crate::analysis::evidence::Sheet { spots: vec![crate::analysis::evidence::Spot { values, covariance }] }
    }
}

/// The `session.json` of a session folder, or the path itself when it is a file.
pub fn session_file(path: &Path) -> PathBuf {
    if path.is_dir() { path.join("session.json") } else { path.to_path_buf() }
}

/// Read a session result from a session folder or its `session.json`.
pub fn read_session(path: &Path) -> Result<SessionResult, CompareError> {
    let file = session_file(path);
    let text = std::fs::read_to_string(&file).map_err(|source| CompareError::Io { path: file.clone(), source })?;
    parse_session(&file, &text)
}

/// Parse the text of a `session.json` (`file` is only for messages).
pub fn parse_session(file: &Path, text: &str) -> Result<SessionResult, CompareError> {
    let root: Value = serde_json::from_str(text).map_err(|e| CompareError::Json { path: file.to_path_buf(), message: e.to_string() })?;
    let missing = |key: &str| CompareError::MissingKey { path: file.to_path_buf(), key: key.to_string() };
    let bad = |key: &str, expected: &'static str| CompareError::BadValue { path: file.to_path_buf(), key: key.to_string(), expected };
    let object = root.as_object().ok_or_else(|| bad("(top level)", "an object"))?;

    let sample = object.get("sample").ok_or_else(|| missing("sample"))?.as_str().ok_or_else(|| bad("sample", "a string"))?.to_string();
    let result = object.get("result").ok_or_else(|| missing("result"))?;
    let result = result.as_object().ok_or_else(|| bad("result", "an object"))?;

    let mut values = [None; 4];
    for (i, name) in ["sigma_deg", "rho_s", "rho_d", "eta"].iter().enumerate() {
        let key = format!("result.{name}");
        values[i] = match result.get(*name).ok_or_else(|| missing(&key))? {
            Value::Null => None,
            v => Some(v.as_f64().filter(|x| x.is_finite()).ok_or_else(|| bad(&key, "a number or null"))?),
        };
    }
    let class = match result.get("class").ok_or_else(|| missing("result.class"))? {
        Value::Null => None,
        v => Some(v.as_str().ok_or_else(|| bad("result.class", "a string or null"))?.to_string()),
    };

    let rows = result.get("covariance").ok_or_else(|| missing("result.covariance"))?;
    let shape = "a 4×4 array of numbers";
    let rows = rows.as_array().filter(|r| r.len() == 4).ok_or_else(|| bad("result.covariance", shape))?;
    let mut covariance = [[0.0; 4]; 4];
    for (i, row) in rows.iter().enumerate() {
        let row = row.as_array().filter(|r| r.len() == 4).ok_or_else(|| bad("result.covariance", shape))?;
        for (j, v) in row.iter().enumerate() {
            // serde_json writes a non-finite covariance as null: treat it as not determined.
            covariance[i][j] = match v {
                Value::Null => 0.0,
                v => v.as_f64().ok_or_else(|| bad("result.covariance", shape))?,
            };
        }
    }
    Ok(SessionResult { file: file.to_path_buf(), sample, class, values, covariance })
}

/// How one parameter was compared.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ParameterComparison {
    /// `sigma`, `rho_s`, `rho_d`, `eta`.
    pub name: &'static str,
    /// Value in A and B (σ in degrees).
    pub a: Option<f64>,
    /// Value in B.
    pub b: Option<f64>,
    /// Standard uncertainty in A and B (σ in degrees), if fitted.
    pub u_a: Option<f64>,
    /// Standard uncertainty in B.
    pub u_b: Option<f64>,
    /// `log` or `linear`: the space the difference was taken in; `None` when skipped.
    pub space: Option<&'static str>,
    /// Difference B − A in that space over its combined standard uncertainty.
    pub z: Option<f64>,
    /// Why the parameter was left out, if it was.
    pub skipped: Option<&'static str>,
}

/// The answer.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Comparison {
    /// Different stock: p < α, or different classes.
    pub distinguishable: bool,
    /// Why: `different classes`, `p < alpha` or `p >= alpha`.
    pub reason: &'static str,
    /// Upper tail of chi-square(dof) at distance²; 1 when nothing could be compared.
    pub p_value: f64,
    /// Mahalanobis distance.
    pub distance: f64,
    /// Parameters compared.
    pub dof: usize,
    /// Significance level used.
    pub alpha: f64,
    /// Class of A (`undecided` when the session could not decide it).
    pub class_a: String,
    /// Class of B.
    pub class_b: String,
    /// Per parameter, in covariance order.
    pub parameters: Vec<ParameterComparison>,
    /// Whether correlations had to be dropped (the summed covariance was not positive definite).
    pub correlations_dropped: bool,
}

/// Compare two sessions at significance level `alpha`.
pub fn compare(a: &SessionResult, b: &SessionResult, alpha: f64) -> Comparison {
    let mut parameters = Vec::with_capacity(4);
    let mut used: Vec<usize> = Vec::new();
    let mut scale_a = [1.0; 4];
    let mut scale_b = [1.0; 4];
    let mut delta = [0.0; 4];
    for i in 0..4 {
        let (va, vb) = (a.values[i], b.values[i]);
        let (var_a, var_b) = (a.covariance[i][i], b.covariance[i][i]);
        let u = |var: f64| (var > 0.0).then(|| var.sqrt());
        let mut p = ParameterComparison { name: PARAM_NAMES[i], a: va, b: vb, u_a: u(var_a), u_b: u(var_b), space: None, z: None, skipped: None };
        match (va, vb) {
            (Some(xa), Some(xb)) if var_a > 0.0 && var_b > 0.0 => {
                let log = i != ETA && xa > 0.0 && xb > 0.0;
                if log {
                    scale_a[i] = 1.0 / xa;
                    scale_b[i] = 1.0 / xb;
                    delta[i] = xb.ln() - xa.ln();
                } else {
                    delta[i] = xb - xa;
                }
                p.space = Some(if log { "log" } else { "linear" });
                let var = var_a * scale_a[i] * scale_a[i] + var_b * scale_b[i] * scale_b[i];
                p.z = Some(delta[i] / var.sqrt());
                used.push(i);
            }
            (None, _) | (_, None) => p.skipped = Some("not determined in both sessions"),
            _ => p.skipped = Some("not fitted in both sessions (zero variance)"),
        }
        parameters.push(p);
    }

    // Summed covariance of the differences in the analysis space, over the used parameters.
    let k = used.len();
    let mut sum = vec![vec![0.0; k]; k];
    for (r, &i) in used.iter().enumerate() {
        for (c, &j) in used.iter().enumerate() {
            sum[r][c] = a.covariance[i][j] * scale_a[i] * scale_a[j] + b.covariance[i][j] * scale_b[i] * scale_b[j];
        }
    }
    let d: Vec<f64> = used.iter().map(|&i| delta[i]).collect();
    let (distance_squared, correlations_dropped) = match mahalanobis_squared(&sum, &d) {
        Some(d2) => (d2, false),
        // Not positive definite (rounding in nearly collinear fits): the diagonal alone.
        None => (d.iter().enumerate().map(|(r, x)| x * x / sum[r][r]).sum(), true),
    };
    let p_value = if k == 0 { 1.0 } else { chi_square_sf(distance_squared, k as f64) };
    // An undecided class is not a measured property: it cannot make the sheets differ.
    let different_classes = matches!((&a.class, &b.class), (Some(x), Some(y)) if x != y);
    let (distinguishable, reason) = if different_classes {
        (true, "different classes")
    } else if p_value < alpha {
        (true, "p < alpha")
    } else {
        (false, "p >= alpha")
    };
    Comparison {
        distinguishable,
        reason,
        p_value,
        distance: distance_squared.sqrt(),
        dof: k,
        alpha,
        class_a: a.class.clone().unwrap_or_else(|| "undecided".into()),
        class_b: b.class.clone().unwrap_or_else(|| "undecided".into()),
        parameters,
        correlations_dropped,
    }
}

/// dᵀ S⁻¹ d by Cholesky; `None` if S is not positive definite.
fn mahalanobis_squared(s: &[Vec<f64>], d: &[f64]) -> Option<f64> {
    let k = d.len();
    let mut l = vec![vec![0.0; k]; k];
    for i in 0..k {
        for j in 0..=i {
            let sum = s[i][j] - (0..j).map(|m| l[i][m] * l[j][m]).sum::<f64>();
            if i == j {
                if sum.is_nan() || sum <= 0.0 {
                    return None;
                }
                l[i][i] = sum.sqrt();
            } else {
                l[i][j] = sum / l[j][j];
            }
        }
    }
    // Solve L y = d; then dᵀ S⁻¹ d = |y|².
    let mut y = vec![0.0; k];
    for i in 0..k {
        y[i] = (d[i] - (0..i).map(|m| l[i][m] * y[m]).sum::<f64>()) / l[i][i];
    }
    Some(y.iter().map(|v| v * v).sum())
}

/// Upper tail P(X > x) of the chi-square distribution with `dof` degrees of freedom.
pub fn chi_square_sf(x: f64, dof: f64) -> f64 {
    if x <= 0.0 { 1.0 } else { regularized_gamma_q(0.5 * dof, 0.5 * x) }
}

/// Regularized upper incomplete gamma Q(a, x) = Γ(a, x) / Γ(a), a > 0, x ≥ 0: by the
/// series of P for x < a + 1 and by the continued fraction of Q otherwise (each converges
/// fast where it is used; Numerical Recipes §6.2), so tiny p-values keep their precision.
pub fn regularized_gamma_q(a: f64, x: f64) -> f64 {
    if x <= 0.0 {
        return 1.0;
    }
    let log_prefactor = a * x.ln() - x - libm::lgamma(a);
    if x < a + 1.0 {
        // P(a, x) = e^(−x) x^a / Γ(a) · Σ x^n / (a (a+1) … (a+n)).
        let mut term = 1.0 / a;
        let mut sum = term;
        let mut ap = a;
        for _ in 0..1000 {
            ap += 1.0;
            term *= x / ap;
            sum += term;
            if term.abs() < sum.abs() * 1e-16 {
                break;
            }
        }
        (1.0 - sum * log_prefactor.exp()).clamp(0.0, 1.0)
    } else {
        // Modified Lentz evaluation of the continued fraction for Γ(a, x) e^x x^(−a).
        let tiny = 1e-300;
        let mut b = x + 1.0 - a;
        let mut c = 1.0 / tiny;
        let mut d = 1.0 / b;
        let mut h = d;
        for i in 1..1000 {
            let an = -(i as f64) * (i as f64 - a);
            b += 2.0;
            d = an * d + b;
            if d.abs() < tiny {
                d = tiny;
            }
            c = b + an / c;
            if c.abs() < tiny {
                c = tiny;
            }
            d = 1.0 / d;
            let step = d * c;
            h *= step;
            if (step - 1.0).abs() < 1e-16 {
                break;
            }
        }
        (log_prefactor.exp() * h).clamp(0.0, 1.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chi_square_matches_known_values() {
        // Critical values from tables (p = 0.05, 0.01) and closed forms for even dof.
        let cases = [
            (3.841_458_820_694_124, 1.0, 0.05),
            (6.634_896_601_021_213, 1.0, 0.01),
            (11.344_866_730_144_373, 3.0, 0.01),
            (9.487_729_036_781_154, 4.0, 0.05),
            (2.0, 2.0, (-1.0f64).exp()),
            (0.5, 4.0, (-0.25f64).exp() * 1.25),
            (100.0, 4.0, (-50.0f64).exp() * 51.0),
            (1e-6, 2.0, (-5e-7f64).exp()),
        ];
        for (x, k, p) in cases {
            let got = chi_square_sf(x, k);
            assert!((got - p).abs() <= 1e-9 * p, "χ²({k}) tail at {x}: {got} vs {p}");
        }
        assert_eq!(chi_square_sf(0.0, 2.0), 1.0);
    }
}
