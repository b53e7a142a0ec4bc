//! The strength of the evidence that two sheets are of the same paper stock, as a
//! likelihood ratio from a two-level model (Aitken & Lucy 2004, the model used for glass
//! and inks): spots of one stock scatter about the stock's mean with a within-stock
//! covariance, and stock means are spread over a population whose density is a kernel
//! estimate over known stocks.
//!
//! LR = p(ȳA, ȳB | same stock) / p(ȳA, ȳB | different stocks), with ȳ a sheet's mean over
//! its spots in (ln σ, ln ρs, ln ρd): the three parameters are positive and their spot-to-
//! spot variation is relative, so they are closest to normal in log space. η is left out:
//! it is a property of the material that barely moves between stocks of a kind and is the
//! worst-determined parameter.
//!
//! With U_X = W/n_X + S_X the variance of sheet X's mean about its stock's mean (W the
//! within-stock covariance per spot, n_X its spots, S_X its fits' mean covariance: the
//! instrument's noise and the calibration's shared errors, which do not average out over
//! spots of one session; counting the noise part in W too errs towards LR = 1) and the
//! population's kernel K = h²·C (C the covariance of the stock means, h Silverman's
//! bandwidth) about each stock mean mᵢ:
//!
//! - same stock: N(ȳA − ȳB; 0, UA + UB) · (1/m) Σᵢ N(θ*; mᵢ, V* + K), where θ* and V* are the
//!   precision-weighted mean of the two sheets and its covariance;
//! - different stocks: Πₓ (1/m) Σᵢ N(ȳX; mᵢ, UX + K).
//!
//! Classes play no part: two sheets either side of a class boundary are weighed by their
//! parameters, not declared different by the boundary.

use crate::analysis::classify::REFERENCES;
use crate::analysis::linalg::{self, Square};
use crate::analysis::model::PARAM_NAMES;
use serde::{Deserialize, Serialize};

/// The parameters compared, in order: σ (degrees), ρs, ρd.
pub const PARAMS: [&str; 3] = [PARAM_NAMES[0], PARAM_NAMES[1], PARAM_NAMES[2]];
/// Their labels for a person.
pub const PARAM_LABELS: [&str; 3] = ["σ (deg)", "ρs", "ρd"];

/// Relative standard deviation per spot of σ, ρs, ρd within a stock in the default
/// population: the between-spot variation (3 % in each) that the forensic study simulates
/// (`--sheet-variation 3`) and docs/FORENSIC.md validates the model at. An assumption about
/// paper, not a measurement of it: a lab's own library replaces it with the variation of
/// its own stocks' spots.
pub const DEFAULT_WITHIN_RELATIVE_SD: [f64; 3] = [0.03, 0.03, 0.03];

/// Relative standard deviation of σ, ρs, ρd between stocks of one kind in the default
/// population: the stock means scatter about each reference paper by 10 % (papers of one
/// kind from different mills differ by a few to a few tens of percent in gloss and
/// brightness). An assumption, and the figure the forensic study draws its stocks with, so
/// that study validates the model under it rather than the figure itself.
pub(crate) const DEFAULT_BETWEEN_RELATIVE_SD: [f64; 3] = [0.10, 0.10, 0.10];

/// |log10 LR| below which the evidence is reported inconclusive (LR between 1/10 and 10:
/// "weak" on the ENFSI scale either way).
pub(crate) const INCONCLUSIVE_LOG10: f64 = 1.0;

/// One spot of a sheet: its fitted σ (degrees), ρs, ρd and their covariance in those
/// units; `None` for a parameter the fit did not determine.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Spot {
    /// σ (degrees), ρs, ρd.
    pub values: [Option<f64>; 3],
    /// Their covariance (rows and columns of undetermined parameters are ignored).
    pub covariance: [[f64; 3]; 3],
}

impl Spot {
    /// A fit's σ (degrees), ρs, ρd and their covariance: `None` for a parameter the fit
    /// did not determine.
    pub(crate) fn of_fit(fit: &crate::analysis::fit::FitResult) -> Spot {
        use crate::analysis::model::{RHO_D, RHO_S, SIGMA};
        let index = [SIGMA, RHO_S, RHO_D];
        Spot {
            values: index.map(|i| fit.reported(i)),
            covariance: std::array::from_fn(|r| {
                std::array::from_fn(|c| fit.covariance[index[r]][index[c]])
            }),
        }
    }

    /// The determined parameters' logs (`None`: not determined or not positive).
    fn log_values(&self) -> [Option<f64>; 3] {
        self.values
            .map(|v| v.filter(|v| *v > 0.0 && v.is_finite()).map(f64::ln))
    }

    /// Covariance of the logs by the delta method: cov(ln a, ln b) = cov(a, b)/(a·b).
    fn log_covariance(&self, params: &[usize]) -> Square {
        let mut s = Square::zeros(params.len());
        for (r, &i) in params.iter().enumerate() {
            for (c, &j) in params.iter().enumerate() {
                let (vi, vj) = (
                    self.values[i].unwrap_or(f64::NAN),
                    self.values[j].unwrap_or(f64::NAN),
                );
                let v = self.covariance[i][j] / (vi * vj);
                *s.at_mut(r, c) = if v.is_finite() { v } else { 0.0 };
            }
        }
        s
    }
}

/// A measured sheet: one or more spots.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Sheet {
    /// Its spots.
    pub spots: Vec<Spot>,
}

impl Sheet {
    /// The parameters every spot determined.
    pub fn determined(&self) -> Vec<usize> {
        (0..3)
            .filter(|&i| {
                !self.spots.is_empty() && self.spots.iter().all(|s| s.log_values()[i].is_some())
            })
            .collect()
    }

    /// Mean of the spots' logs over `params`.
    fn mean_log(&self, params: &[usize]) -> Vec<f64> {
        let n = self.spots.len().max(1) as f64;
        params
            .iter()
            .map(|&i| {
                self.spots
                    .iter()
                    .filter_map(|s| s.log_values()[i])
                    .sum::<f64>()
                    / n
            })
            .collect()
    }

    /// Mean of the spots' log covariances over `params`.
    fn mean_log_covariance(&self, params: &[usize]) -> Square {
        let mut s = Square::zeros(params.len());
        for spot in &self.spots {
            let c = spot.log_covariance(params);
            s.a.iter_mut()
                .zip(&c.a)
                .for_each(|(a, b)| *a += b / self.spots.len() as f64);
        }
        s
    }
}

/// Each stock's sheets pooled as one sheet of all their spots, by stock name (sorted),
/// with how many sheets went into it.
pub(crate) fn pool_by_stock(sheets: &[(String, Sheet)]) -> Vec<(String, usize, Sheet)> {
    let mut pooled: std::collections::BTreeMap<&str, (usize, Sheet)> = Default::default();
    for (stock, sheet) in sheets {
        let entry = pooled
            .entry(stock)
            .or_insert_with(|| (0, Sheet { spots: Vec::new() }));
        entry.0 += 1;
        entry.1.spots.extend(sheet.spots.iter().cloned());
    }
    pooled
        .into_iter()
        .map(|(stock, (n, sheet))| (stock.to_string(), n, sheet))
        .collect()
}

/// One stock of a search, with the evidence of the searched sheet against it.
#[derive(Clone, Debug, PartialEq)]
pub struct RankedStock {
    /// The stock's name.
    pub stock: String,
    /// Its sheets and spots, pooled.
    pub sheets: usize,
    /// Its spots.
    pub spots: usize,
    /// The searched sheet against the pooled stock.
    pub evidence: Evidence,
}

/// The stocks of `library` (sheets labelled by stock) ranked by the likelihood ratio of
/// `query` against each stock's sheets pooled as one sheet: best first, a NaN last, ties
/// by name. What `gonio library search` prints and the forensic study counts.
pub fn rank_stocks(
    query: &Sheet,
    library: &[(String, Sheet)],
    population: &Population,
) -> Vec<RankedStock> {
    let mut ranking: Vec<RankedStock> = pool_by_stock(library)
        .into_iter()
        .map(|(stock, sheets, pooled)| RankedStock {
            stock,
            sheets,
            spots: pooled.spots.len(),
            evidence: likelihood_ratio(query, &pooled, population),
        })
        .collect();
    let lr = |r: &RankedStock| r.evidence.log10_lr;
    ranking.sort_by(|a, b| {
        lr(b)
            .partial_cmp(&lr(a))
            .unwrap_or_else(|| lr(a).is_nan().cmp(&lr(b).is_nan()))
            .then_with(|| a.stock.cmp(&b.stock))
    });
    ranking
}

fn scatter(rows: impl Iterator<Item = Vec<f64>>, mean: &[f64], dof: usize) -> Square {
    let d = mean.len();
    let mut s = Square::zeros(d);
    for row in rows {
        for r in 0..d {
            for c in 0..d {
                *s.at_mut(r, c) += (row[r] - mean[r]) * (row[c] - mean[c]);
            }
        }
    }
    let dof = dof.max(1) as f64;
    s.a.iter_mut().for_each(|v| *v /= dof);
    s
}

/// Why a population could not be made.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum EvidenceError {
    /// Too few stocks for a between-stock density.
    #[error(
        "a population needs sheets of at least {needed} stocks with σ, ρs and ρd determined; it has {found}"
    )]
    TooFewStocks {
        /// Stocks needed.
        needed: usize,
        /// Stocks given.
        found: usize,
    },
    /// No stock has two spots to estimate the within-stock variation from.
    #[error("no stock has two or more spots: the within-stock variation cannot be estimated")]
    NoWithinStockVariation,
    /// The variation came out degenerate (a parameter that never varies).
    #[error(
        "the population's {what} covariance is not positive definite (a parameter that does not vary)"
    )]
    Degenerate {
        /// Within or between.
        what: &'static str,
    },
}

/// Where a population came from.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum PopulationSource {
    /// The documented default: the reference papers of Table 6 with
    /// [`DEFAULT_WITHIN_RELATIVE_SD`].
    Default,
    /// Sheets of known stocks (a library).
    Sheets {
        /// Stocks.
        stocks: usize,
        /// Sheets.
        sheets: usize,
        /// Spots.
        spots: usize,
    },
}

/// The population of stocks the evidence is weighed against: stock means in log space,
/// the within-stock covariance per spot, the between-stock covariance.
#[derive(Clone, Debug, PartialEq)]
pub struct Population {
    /// Each stock's name and mean (ln σ, ln ρs, ln ρd).
    pub stocks: Vec<(String, [f64; 3])>,
    /// Within-stock covariance per spot, log space.
    pub within: [[f64; 3]; 3],
    /// Covariance of the population's density about each stock mean (its kernel), log
    /// space: h²·C (C the stock means' covariance, h Silverman's bandwidth) for a library,
    /// [`DEFAULT_BETWEEN_RELATIVE_SD`] about each reference paper for the default.
    pub(crate) kernel: [[f64; 3]; 3],
    /// Where it came from.
    pub source: PopulationSource,
}

fn to_array(s: &Square) -> [[f64; 3]; 3] {
    std::array::from_fn(|r| std::array::from_fn(|c| s.at(r, c)))
}

fn restrict(m: &[[f64; 3]; 3], params: &[usize]) -> Square {
    let mut s = Square::zeros(params.len());
    for (r, &i) in params.iter().enumerate() {
        for (c, &j) in params.iter().enumerate() {
            *s.at_mut(r, c) = m[i][j];
        }
    }
    s
}

impl Population {
    /// From sheets labelled by stock (a library's contents). Stocks whose spots did not all
    /// determine σ, ρs and ρd are left out; the within-stock covariance is pooled over every
    /// stock's spots about its mean (sheets of a stock differ as its spots do).
    pub fn from_sheets(sheets: &[(String, Sheet)]) -> Result<Population, EvidenceError> {
        // Only sheets whose every spot determined σ, ρs and ρd describe a stock in full.
        let complete: Vec<(String, Sheet)> = sheets
            .iter()
            .filter(|(_, sheet)| sheet.determined().len() == 3)
            .cloned()
            .collect();
        let mut stocks = Vec::new();
        let mut rows_about_mean: Vec<Vec<f64>> = Vec::new();
        let mut dof = 0usize;
        let (mut n_sheets, mut n_spots) = (0, 0);
        for (name, sheets_of_stock, pooled) in pool_by_stock(&complete) {
            n_sheets += sheets_of_stock;
            n_spots += pooled.spots.len();
            let mean = pooled.mean_log(&[0, 1, 2]);
            rows_about_mean.extend(pooled.spots.iter().map(|s| {
                (0..3)
                    .map(|i| s.log_values()[i].unwrap_or(f64::NAN) - mean[i])
                    .collect::<Vec<f64>>()
            }));
            dof += pooled.spots.len() - 1;
            stocks.push((name, [mean[0], mean[1], mean[2]]));
        }
        const MIN_STOCKS: usize = 4;
        if stocks.len() < MIN_STOCKS {
            return Err(EvidenceError::TooFewStocks {
                needed: MIN_STOCKS,
                found: stocks.len(),
            });
        }
        if dof == 0 {
            return Err(EvidenceError::NoWithinStockVariation);
        }
        let within = scatter(rows_about_mean.into_iter(), &[0.0; 3], dof);
        let means: Vec<Vec<f64>> = stocks.iter().map(|(_, m)| m.to_vec()).collect();
        let grand: Vec<f64> = (0..3)
            .map(|i| means.iter().map(|m| m[i]).sum::<f64>() / means.len() as f64)
            .collect();
        let between = scatter(means.into_iter(), &grand, stocks.len() - 1);
        if linalg::cholesky(&within).is_none() {
            return Err(EvidenceError::Degenerate {
                what: "within-stock",
            });
        }
        if linalg::cholesky(&between).is_none() {
            return Err(EvidenceError::Degenerate {
                what: "between-stock",
            });
        }
        let n_stocks = stocks.len();
        let kernel = scale(&between, silverman_bandwidth(n_stocks, 3).powi(2));
        Ok(Population {
            stocks,
            within: to_array(&within),
            kernel: to_array(&kernel),
            source: PopulationSource::Sheets {
                stocks: n_stocks,
                sheets: n_sheets,
                spots: n_spots,
            },
        })
    }

    /// The documented default population when there is no library: stocks of the kinds of
    /// the eight reference papers of Table 6, their means scattered about each paper by
    /// [`DEFAULT_BETWEEN_RELATIVE_SD`], with [`DEFAULT_WITHIN_RELATIVE_SD`] between spots.
    pub fn default_population() -> Population {
        let stocks: Vec<(String, [f64; 3])> = REFERENCES
            .iter()
            .map(|r| {
                (
                    r.name.to_string(),
                    [
                        r.params.sigma_deg.ln(),
                        r.params.rho_s.ln(),
                        r.params.rho_d.ln(),
                    ],
                )
            })
            .collect();
        let log_variance = |sd: &[f64; 3]| -> [[f64; 3]; 3] {
            std::array::from_fn(|r| {
                std::array::from_fn(|c| {
                    if r == c {
                        (1.0 + sd[r].powi(2)).ln()
                    } else {
                        0.0
                    }
                })
            })
        };
        Population {
            stocks,
            within: log_variance(&DEFAULT_WITHIN_RELATIVE_SD),
            kernel: log_variance(&DEFAULT_BETWEEN_RELATIVE_SD),
            source: PopulationSource::Default,
        }
    }

    /// The number of stocks.
    pub fn len(&self) -> usize {
        self.stocks.len()
    }

    /// Whether it has no stocks.
    pub fn is_empty(&self) -> bool {
        self.stocks.is_empty()
    }
}

/// Which way the evidence points.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Support {
    /// log10 LR ≥ [`INCONCLUSIVE_LOG10`]: supports the same stock.
    SameStock,
    /// log10 LR ≤ −[`INCONCLUSIVE_LOG10`]: supports different stocks.
    DifferentStocks,
    /// Between: the evidence does not discriminate.
    Inconclusive,
}

/// The weighed evidence of two sheets.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Evidence {
    /// log10 of the likelihood ratio (same stock : different stocks).
    pub log10_lr: f64,
    /// Its verbal equivalent on the ENFSI scale.
    pub verbal: String,
    /// Which way it points.
    pub support: Support,
    /// The parameters compared (names of [`PARAMS`]).
    pub parameters: Vec<&'static str>,
    /// The parameters left out, with why.
    pub left_out: Vec<(&'static str, &'static str)>,
    /// log10 LR of each compared parameter alone: the main contributors (they do not add
    /// up to the whole, which accounts for the parameters' correlation).
    pub contributions: Vec<(&'static str, f64)>,
    /// Spots of A and of B.
    pub n_spots: (usize, usize),
    /// Whether each sheet's own spots could show its within-sheet variation (two or more).
    pub within_known: (bool, bool),
}

/// The ENFSI verbal scale for a log10 likelihood ratio.
pub fn verbal(log10_lr: f64) -> String {
    let magnitude = log10_lr.abs();
    let strength = if magnitude < 1.0 {
        "weak"
    } else if magnitude < 2.0 {
        "moderate"
    } else if magnitude < 3.0 {
        "moderately strong"
    } else if magnitude < 4.0 {
        "strong"
    } else if magnitude < 6.0 {
        "very strong"
    } else {
        "extremely strong"
    };
    if magnitude < 1e-9 {
        "no support for either proposition".to_string()
    } else if log10_lr > 0.0 {
        format!("{strength} support for the same stock over different stocks")
    } else {
        format!("{strength} support for different stocks over the same stock")
    }
}

/// Silverman's bandwidth for a d-dimensional normal kernel over m stock means.
fn silverman_bandwidth(m: usize, d: usize) -> f64 {
    (4.0 / (m.max(1) as f64 * (d as f64 + 2.0))).powf(1.0 / (d as f64 + 4.0))
}

/// ln N(x; mean, cov) by Cholesky; `None` when cov is not positive definite.
fn log_normal_density(x: &[f64], mean: &[f64], cov: &Square) -> Option<f64> {
    let l = linalg::cholesky(cov)?;
    let mut w: Vec<f64> = x.iter().zip(mean).map(|(a, b)| a - b).collect();
    linalg::forward_substitute(&l, &mut w);
    let quad: f64 = w.iter().map(|v| v * v).sum();
    let log_det: f64 = (0..l.n).map(|i| 2.0 * l.at(i, i).ln()).sum();
    Some(-0.5 * (x.len() as f64 * (2.0 * std::f64::consts::PI).ln() + log_det + quad))
}

fn add(a: &Square, b: &Square) -> Square {
    Square {
        n: a.n,
        a: a.a.iter().zip(&b.a).map(|(x, y)| x + y).collect(),
    }
}

fn scale(a: &Square, f: f64) -> Square {
    Square {
        n: a.n,
        a: a.a.iter().map(|x| x * f).collect(),
    }
}

fn log_mean_exp(values: &[f64]) -> f64 {
    let max = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if !max.is_finite() {
        return max;
    }
    max + (values.iter().map(|v| (v - max).exp()).sum::<f64>() / values.len() as f64).ln()
}

/// ln LR over `params` (indices into σ, ρs, ρd); `None` when a covariance is degenerate.
fn log_lr(a: &Sheet, b: &Sheet, population: &Population, params: &[usize]) -> Option<f64> {
    let d = params.len();
    let within = restrict(&population.within, params);
    let kernel = restrict(&population.kernel, params);
    let (ya, yb) = (a.mean_log(params), b.mean_log(params));
    let ua = add(
        &scale(&within, 1.0 / a.spots.len() as f64),
        &a.mean_log_covariance(params),
    );
    let ub = add(
        &scale(&within, 1.0 / b.spots.len() as f64),
        &b.mean_log_covariance(params),
    );
    let means: Vec<Vec<f64>> = population
        .stocks
        .iter()
        .map(|(_, m)| params.iter().map(|&i| m[i]).collect())
        .collect();
    // Same stock: the difference, and the precision-weighted mean against the population.
    let difference = log_normal_density(
        &ya.iter().zip(&yb).map(|(p, q)| p - q).collect::<Vec<_>>(),
        &vec![0.0; d],
        &add(&ua, &ub),
    )?;
    let (pa, pb) = (linalg::spd_inverse(&ua)?, linalg::spd_inverse(&ub)?);
    let v_star = linalg::spd_inverse(&add(&pa, &pb))?;
    let weighted: Vec<f64> = (0..d)
        .map(|r| {
            (0..d)
                .map(|c| pa.at(r, c) * ya[c] + pb.at(r, c) * yb[c])
                .sum()
        })
        .collect();
    let theta: Vec<f64> = (0..d)
        .map(|r| (0..d).map(|c| v_star.at(r, c) * weighted[c]).sum())
        .collect();
    let around = add(&v_star, &kernel);
    let same_density: Vec<f64> = means
        .iter()
        .map(|m| log_normal_density(&theta, m, &around))
        .collect::<Option<_>>()?;
    let numerator = difference + log_mean_exp(&same_density);
    // Different stocks: each sheet against the population on its own.
    let (ka, kb) = (add(&ua, &kernel), add(&ub, &kernel));
    let da: Vec<f64> = means
        .iter()
        .map(|m| log_normal_density(&ya, m, &ka))
        .collect::<Option<_>>()?;
    let db: Vec<f64> = means
        .iter()
        .map(|m| log_normal_density(&yb, m, &kb))
        .collect::<Option<_>>()?;
    let denominator = log_mean_exp(&da) + log_mean_exp(&db);
    let out = numerator - denominator;
    out.is_finite().then_some(out)
}

/// The likelihood ratio of "A and B are the same stock" against "different stocks", over
/// the parameters both sheets determined; a sheet with no determined parameter, or a
/// degenerate covariance, gives LR = 1 with the reason in `left_out`.
pub fn likelihood_ratio(a: &Sheet, b: &Sheet, population: &Population) -> Evidence {
    let (da, db) = (a.determined(), b.determined());
    let params: Vec<usize> = (0..3)
        .filter(|i| da.contains(i) && db.contains(i))
        .collect();
    let left_out: Vec<(&'static str, &'static str)> = (0..3)
        .filter(|i| !params.contains(i))
        .map(|i| {
            (
                PARAMS[i],
                if !da.contains(&i) && !db.contains(&i) {
                    "determined by neither sheet"
                } else if !da.contains(&i) {
                    "not determined by A"
                } else {
                    "not determined by B"
                },
            )
        })
        .collect();
    let ln10 = std::f64::consts::LN_10;
    let joint = if params.is_empty() || population.is_empty() {
        None
    } else {
        log_lr(a, b, population, &params)
    };
    let log10_lr = joint.map_or(0.0, |v| v / ln10);
    let contributions = params
        .iter()
        .map(|&i| {
            (
                PARAMS[i],
                log_lr(a, b, population, &[i]).map_or(0.0, |v| v / ln10),
            )
        })
        .collect();
    let support = if log10_lr >= INCONCLUSIVE_LOG10 {
        Support::SameStock
    } else if log10_lr <= -INCONCLUSIVE_LOG10 {
        Support::DifferentStocks
    } else {
        Support::Inconclusive
    };
    let mut left_out = left_out;
    if joint.is_none() && !params.is_empty() {
        left_out.push((
            "all",
            "a covariance was not positive definite: no evidence weighed",
        ));
    }
    Evidence {
        log10_lr,
        verbal: verbal(log10_lr),
        support,
        parameters: params.iter().map(|&i| PARAMS[i]).collect(),
        left_out,
        contributions,
        n_spots: (a.spots.len(), b.spots.len()),
        within_known: (a.spots.len() >= 2, b.spots.len() >= 2),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spot(sigma: f64, rho_s: f64, rho_d: f64, relative_u: f64) -> Spot {
        let values = [sigma, rho_s, rho_d];
        Spot {
            values: values.map(Some),
            covariance: std::array::from_fn(|r| {
                std::array::from_fn(|c| {
                    if r == c {
                        (values[r] * relative_u).powi(2)
                    } else {
                        0.0
                    }
                })
            }),
        }
    }

    fn sheet(spots: &[(f64, f64, f64)]) -> Sheet {
        Sheet {
            spots: spots
                .iter()
                .map(|&(a, b, c)| spot(a, b, c, 0.002))
                .collect(),
        }
    }

    #[test]
    fn the_ratio_is_symmetric_and_falls_as_the_sheets_part() {
        let p = Population::default_population();
        let a = sheet(&[(21.7, 0.409, 0.414)]);
        let mut last = f64::INFINITY;
        for step in [0.0, 0.02, 0.05, 0.1, 0.2] {
            let b = sheet(&[(21.7 * (1.0 + step), 0.409, 0.414 * (1.0 + step))]);
            let (ab, ba) = (likelihood_ratio(&a, &b, &p), likelihood_ratio(&b, &a, &p));
            assert!((ab.log10_lr - ba.log10_lr).abs() < 1e-9, "symmetric");
            assert!(ab.log10_lr < last, "{step}: {} after {last}", ab.log10_lr);
            last = ab.log10_lr;
        }
        assert!(last < -2.0, "20 % apart in σ and ρd: {last}");
    }

    #[test]
    fn more_spots_weigh_more() {
        let p = Population::default_population();
        let one = likelihood_ratio(
            &sheet(&[(21.7, 0.409, 0.414)]),
            &sheet(&[(21.7, 0.409, 0.414)]),
            &p,
        );
        let five = likelihood_ratio(
            &sheet(&[(21.7, 0.409, 0.414); 5]),
            &sheet(&[(21.7, 0.409, 0.414); 5]),
            &p,
        );
        assert!(five.log10_lr > one.log10_lr && one.log10_lr > 0.0);
        assert_eq!(five.within_known, (true, true));
        assert_eq!(one.within_known, (false, false));
    }

    #[test]
    fn an_undetermined_parameter_is_left_out_with_the_reason() {
        let p = Population::default_population();
        let a = sheet(&[(21.7, 0.409, 0.414)]);
        let mut b = a.clone();
        b.spots[0].values[1] = None;
        let e = likelihood_ratio(&a, &b, &p);
        assert_eq!(e.parameters, ["sigma_deg", "rho_d"]);
        assert_eq!(e.left_out, [("rho_s", "not determined by B")]);
        assert!(e.log10_lr.is_finite());
        let none = Sheet {
            spots: vec![Spot {
                values: [None; 3],
                covariance: [[0.0; 3]; 3],
            }],
        };
        let e = likelihood_ratio(&a, &none, &p);
        assert_eq!((e.log10_lr, e.support), (0.0, Support::Inconclusive));
    }

    #[test]
    fn a_population_needs_stocks_and_spots() {
        let one_each: Vec<(String, Sheet)> = (0..6)
            .map(|k| (format!("s{k}"), sheet(&[(10.0 + k as f64, 0.4, 0.4)])))
            .collect();
        assert_eq!(
            Population::from_sheets(&one_each),
            Err(EvidenceError::NoWithinStockVariation)
        );
        let few: Vec<(String, Sheet)> = (0..2)
            .map(|k| {
                (
                    format!("s{k}"),
                    sheet(&[(10.0, 0.4, 0.4), (10.2, 0.41, 0.39)]),
                )
            })
            .collect();
        assert!(matches!(
            Population::from_sheets(&few),
            Err(EvidenceError::TooFewStocks { found: 2, .. })
        ));
        let good: Vec<(String, Sheet)> = (0..6)
            .map(|k| {
                let (x, y, z) = (
                    1.0 + 0.3 * k as f64,
                    0.4 + 0.07 * (k % 3) as f64,
                    0.4 + 0.05 * (k % 4) as f64,
                );
                let e = 0.01 * (k as f64 - 2.5);
                (
                    format!("s{k}"),
                    sheet(&[
                        (10.0 * x, y, z),
                        (10.3 * x, (0.98 + e) * y, 1.02 * z),
                        (9.8 * x, 1.02 * y, (0.99 - e) * z),
                    ]),
                )
            })
            .collect();
        let p = Population::from_sheets(&good).expect("six stocks of three spots");
        assert_eq!(
            p.source,
            PopulationSource::Sheets {
                stocks: 6,
                sheets: 6,
                spots: 18
            }
        );
    }

    #[test]
    fn the_verbal_scale_follows_enfsi() {
        assert_eq!(
            verbal(0.5),
            "weak support for the same stock over different stocks"
        );
        assert_eq!(
            verbal(-1.5),
            "moderate support for different stocks over the same stock"
        );
        assert_eq!(
            verbal(2.5),
            "moderately strong support for the same stock over different stocks"
        );
        assert_eq!(
            verbal(3.5),
            "strong support for the same stock over different stocks"
        );
        assert_eq!(
            verbal(-5.0),
            "very strong support for different stocks over the same stock"
        );
        assert_eq!(
            verbal(7.0),
            "extremely strong support for the same stock over different stocks"
        );
        assert_eq!(verbal(0.0), "no support for either proposition");
    }
}
