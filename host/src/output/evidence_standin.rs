//! TEMPORARY STAND-IN for `host/src/analysis/evidence.rs`, which is being written in
//! parallel on main. It has the agreed public API (`Spot`, `Sheet`, `Population`,
//! `Evidence`, `likelihood_ratio`) so that the library and `gonio library search` can be
//! built and tested now. At merge: delete this file and its line in `output/mod.rs`, and
//! change the one `use` in `output/library.rs` and `cli/library.rs` to
//! `crate::analysis::evidence`.
//!
//! Its model is deliberately crude (not for casework): each sheet is the mean of its
//! spots, each parameter compared on its own (diagonal covariance), Gaussian within stock
//! (the spots' own variances) and between stocks (the variance of the stocks' means).
use serde::{Deserialize, Serialize};
use thiserror::Error;

/// One spot of a sheet: the fitted σ (degrees), ρs, ρd and their 3×3 covariance in those
/// units. `None` for a parameter the fit did not determine.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Spot {
    /// σ [deg], ρs, ρd.
    pub values: [Option<f64>; 3],
    /// Their covariance.
    pub covariance: [[f64; 3]; 3],
}

/// A measured sheet: one or more spots.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Sheet {
    /// Its spots.
    pub spots: Vec<Spot>,
}

/// Why a population cannot be made.
#[derive(Debug, Error)]
pub enum EvidenceError {
    /// Fewer than two stocks: no between-stock spread can be estimated.
    #[error("the population needs sheets of at least two stocks, it has {0}")]
    TooFewStocks(usize),
}

/// The population of stocks the evidence is weighed against: the between-stock variance
/// of each parameter.
#[derive(Clone, Debug)]
pub struct Population {
    between_variance: [f64; 3],
}

/// Per-parameter mean and variance of the mean of a sheet, `None` where no spot
/// determined the parameter.
fn sheet_mean(sheet: &Sheet) -> [Option<(f64, f64)>; 3] {
    let mut out = [None; 3];
    for (k, slot) in out.iter_mut().enumerate() {
        let determined: Vec<(f64, f64)> = sheet.spots.iter().filter_map(|s| s.values[k].map(|v| (v, s.covariance[k][k].max(0.0)))).collect();
        if determined.is_empty() {
            continue;
        }
        let n = determined.len() as f64;
        let mean = determined.iter().map(|d| d.0).sum::<f64>() / n;
        let variance = determined.iter().map(|d| d.1).sum::<f64>() / (n * n);
        *slot = Some((mean, variance));
    }
    out
}

impl Population {
    /// From sheets labelled by stock (the library's contents).
    pub fn from_sheets(sheets: &[(String, Sheet)]) -> Result<Population, EvidenceError> {
        let mut stocks: std::collections::BTreeMap<&str, Vec<Spot>> = Default::default();
        for (stock, sheet) in sheets {
            stocks.entry(stock).or_default().extend(sheet.spots.iter().cloned());
        }
        if stocks.len() < 2 {
            return Err(EvidenceError::TooFewStocks(stocks.len()));
        }
        let means: Vec<_> = stocks.into_values().map(|spots| sheet_mean(&Sheet { spots })).collect();
        let mut between_variance = Population::default_population().between_variance;
        for (k, slot) in between_variance.iter_mut().enumerate() {
            let values: Vec<f64> = means.iter().filter_map(|m| m[k].map(|x| x.0)).collect();
            if values.len() >= 2 {
                let n = values.len() as f64;
                let mean = values.iter().sum::<f64>() / n;
                *slot = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
            }
        }
        Ok(Population { between_variance })
    }

    /// The default population when there is no library (rough spreads of white papers).
    pub fn default_population() -> Population {
        Population { between_variance: [3.0f64.powi(2), 0.5f64.powi(2), 0.05f64.powi(2)] }
    }
}

/// The weight of evidence.
#[derive(Clone, Debug, PartialEq)]
pub struct Evidence {
    /// log10 of the likelihood ratio (same stock : different stocks).
    pub log10_lr: f64,
    /// Verbal equivalent.
    pub verbal: &'static str,
}

/// Likelihood ratio of "A and B are the same stock" against "different stocks".
pub fn likelihood_ratio(a: &Sheet, b: &Sheet, population: &Population) -> Evidence {
    let (ma, mb) = (sheet_mean(a), sheet_mean(b));
    let mut ln_lr = 0.0;
    for k in 0..3 {
        let (Some((xa, va)), Some((xb, vb))) = (ma[k], mb[k]) else { continue };
        let within = (va + vb).max(1e-12);
        let different = within + 2.0 * population.between_variance[k];
        let d2 = (xa - xb).powi(2);
        ln_lr += -0.5 * (d2 / within + within.ln()) + 0.5 * (d2 / different + different.ln());
    }
    let log10_lr = ln_lr / std::f64::consts::LN_10;
    let verbal = match log10_lr {
        x if x >= 4.0 => "very strong support for same stock",
        x if x >= 2.0 => "strong support for same stock",
        x if x >= 1.0 => "moderate support for same stock",
        x if x > -1.0 => "inconclusive",
        x if x > -2.0 => "moderate support for different stocks",
        x if x > -4.0 => "strong support for different stocks",
        _ => "very strong support for different stocks",
    };
    Evidence { log10_lr, verbal }
}
