//! The population the evidence is weighed against, estimated from a library of sheets of
//! known stocks: three levels (spots within a sheet, sheets within a stock, stocks in the
//! population), each variance with its degrees of freedom, and a kernel density of the
//! stock means whose bandwidth the stocks themselves choose.
//!
//! Why each choice:
//! - Every variance the ratio uses is its one-sided 95 % upper confidence bound, not the
//!   estimate: a within-stock variance under-estimated from few sheets is what made
//!   same-stock pairs "extremely strong support for different stocks"; a larger one only
//!   moves ratios towards 1.
//! - The sheet level is what the library's repeated sheets of one stock show beyond their
//!   spots' scatter (a method-of-moments estimate: the sheet means' scatter less the
//!   spot variance over the spots per sheet). Without a stock of two sheets it cannot be
//!   measured; it is then taken equal to the spot level and the population says so.
//! - The kernel is h²·B with B the spread of the stock means less what their own
//!   estimation noise explains (deconvolved), and h the value in (0, 1] that maximises the
//!   leave-one-stock-out likelihood of the stock means. Silverman's rule on pooled glossy
//!   and rough stocks gave kernels of 73–302 % where stocks of a kind differ by about 10 %;
//!   the likelihood picks the scale at which stocks actually neighbour each other, and
//!   h ≤ 1 keeps the kernel within the data's own spread.
use super::density::{
    Cov3, Factor, Small, add3, log_mean_exp, positive_definite_or_diagonal, restrict, scale3,
    scatter, upper_variance, with_variances,
};
use super::{EvidenceError, Sheet};
use crate::analysis::classify::REFERENCES;
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, BTreeSet};

/// Fewest stocks a population is estimated from.
pub(crate) const MIN_STOCKS: usize = 4;

/// Relative standard deviation per spot of σ, ρs, ρd within a sheet in the demonstration
/// population: an assumption, not a measurement (a lab's library replaces it).
pub(crate) const DEMONSTRATION_SPOT_RELATIVE_SD: [f64; 3] = [0.03, 0.03, 0.03];
/// Relative standard deviation of a sheet's mean about its stock in the demonstration
/// population: an assumption.
pub(crate) const DEMONSTRATION_SHEET_RELATIVE_SD: [f64; 3] = [0.03, 0.03, 0.03];
/// Relative standard deviation of stock means about each reference paper in the
/// demonstration population: an assumption.
pub(crate) const DEMONSTRATION_BETWEEN_RELATIVE_SD: [f64; 3] = [0.10, 0.10, 0.10];

/// A sheet of a known stock, as a library holds it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LibrarySheet {
    /// Its stock.
    pub stock: String,
    /// Its lot or ream, when recorded.
    pub lot: Option<String>,
    /// The instrument that measured it (serial number), when recorded.
    pub instrument: Option<String>,
    /// Its spots.
    pub sheet: Sheet,
}

/// One level's covariance (log space) as estimated and as the ratio uses it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Component {
    /// The estimate (its variances floored at 0).
    pub estimate: Cov3,
    /// Degrees of freedom behind it; 0: not measured.
    pub dof: usize,
    /// What the ratio uses: each variance at its one-sided 95 % upper confidence bound, with
    /// the estimate's correlations; for a level not measured, the assumption stated.
    pub used: Cov3,
}

impl Component {
    /// Whether the library measured it.
    pub fn measured(&self) -> bool {
        self.dof > 0
    }

    /// The relative standard deviation of each parameter the ratio uses (from the log
    /// variance: √(e^v − 1)).
    pub(crate) fn used_relative_sd(&self) -> [f64; 3] {
        std::array::from_fn(|i| self.used[i][i].max(0.0).exp_m1().sqrt())
    }
}

/// One stock of the population: its mean and how well the library knows it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StockMean {
    /// Its name.
    pub name: String,
    /// Mean (ln σ, ln ρs, ln ρd) of its sheets' means.
    pub mean: [f64; 3],
    /// The covariance of that mean as an estimate of the stock's.
    pub covariance: Cov3,
    /// Its sheets.
    pub sheets: usize,
}

/// Where a population came from.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum PopulationSource {
    /// The eight reference papers with assumed variations: for demonstration, not evidence.
    Demonstration,
    /// A library of measured sheets of known stocks.
    Library {
        /// Stocks used.
        stocks: usize,
        /// Distinct lots recorded among them.
        lots: usize,
        /// Sheets used.
        sheets: usize,
        /// Spots used.
        spots: usize,
        /// Distinct instruments that measured them.
        instruments: usize,
        /// Sheets left out because a spot did not determine σ, ρs and ρd.
        left_out_sheets: usize,
    },
}

/// The population of stocks the evidence is weighed against.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Population {
    /// Its stocks.
    pub stocks: Vec<StockMean>,
    /// Spots about their sheet's mean, per spot.
    pub spot: Component,
    /// Sheets' means about their stock's mean.
    pub sheet: Component,
    /// The kernel of the stock-mean density about each stock (log space).
    pub kernel: Cov3,
    /// Its bandwidth h (kernel = h²·the deconvolved spread of stock means); `None` for the
    /// demonstration population, whose kernel is assumed.
    pub bandwidth: Option<f64>,
    /// Where it came from.
    pub source: PopulationSource,
    /// Its validation: the calibrator and bounds comparisons use; `None` until validated.
    pub validation: Option<super::Validation>,
}

/// One sheet's spots in log space, all three parameters determined.
struct LogSheet {
    spots: Vec<[f64; 3]>,
    mean: [f64; 3],
}

impl LogSheet {
    fn of(sheet: &Sheet) -> Option<LogSheet> {
        let spots: Vec<[f64; 3]> = sheet
            .spots
            .iter()
            .map(|s| {
                let v = s.log_values();
                Some([v[0]?, v[1]?, v[2]?])
            })
            .collect::<Option<_>>()?;
        if spots.is_empty() {
            return None;
        }
        Some(LogSheet {
            mean: mean_of(&spots),
            spots,
        })
    }
}

fn mean_of(rows: &[[f64; 3]]) -> [f64; 3] {
    let n = rows.len().max(1) as f64;
    std::array::from_fn(|i| rows.iter().map(|r| r[i]).sum::<f64>() / n)
}

fn diagonal(m: &Cov3) -> [f64; 3] {
    std::array::from_fn(|i| m[i][i])
}

/// The log variances of relative standard deviations.
pub(crate) fn log_variances(relative_sd: &[f64; 3]) -> Cov3 {
    std::array::from_fn(|r| {
        std::array::from_fn(|c| {
            if r == c {
                (1.0 + relative_sd[r].powi(2)).ln()
            } else {
                0.0
            }
        })
    })
}

impl Population {
    /// Estimated from sheets of known stocks (a library). Sheets with a spot that did not
    /// determine σ, ρs and ρd are left out (counted in the source).
    pub(crate) fn from_library(sheets: &[LibrarySheet]) -> Result<Population, EvidenceError> {
        let mut by_stock: BTreeMap<&str, Vec<LogSheet>> = BTreeMap::new();
        let mut lots = BTreeSet::new();
        let mut instruments = BTreeSet::new();
        let mut left_out_sheets = 0;
        for s in sheets {
            match LogSheet::of(&s.sheet) {
                Some(log) => {
                    by_stock.entry(&s.stock).or_default().push(log);
                    if let Some(lot) = &s.lot {
                        lots.insert((s.stock.as_str(), lot.as_str()));
                    }
                    if let Some(instrument) = &s.instrument {
                        instruments.insert(instrument.as_str());
                    }
                }
                None => left_out_sheets += 1,
            }
        }
        if by_stock.len() < MIN_STOCKS {
            return Err(EvidenceError::TooFewStocks {
                needed: MIN_STOCKS,
                found: by_stock.len(),
            });
        }
        let all: Vec<&LogSheet> = by_stock.values().flatten().collect();
        let spot = spot_level(&all);
        let sheet = sheet_level(&by_stock, &spot)?;
        // Stock means and how well each is known.
        let stocks: Vec<StockMean> = by_stock
            .iter()
            .map(|(name, sheets)| {
                let means: Vec<[f64; 3]> = sheets.iter().map(|s| s.mean).collect();
                let j = sheets.len() as f64;
                let inverse_n = sheets
                    .iter()
                    .map(|s| 1.0 / s.spots.len() as f64)
                    .sum::<f64>()
                    / j;
                StockMean {
                    name: name.to_string(),
                    mean: mean_of(&means),
                    covariance: scale3(&add3(&sheet.used, &scale3(&spot.used, inverse_n)), 1.0 / j),
                    sheets: sheets.len(),
                }
            })
            .collect();
        let (kernel, bandwidth) = choose_kernel(&stocks).ok_or(EvidenceError::Degenerate {
            what: "between-stock",
        })?;
        let population = Population {
            stocks,
            spot,
            sheet,
            kernel,
            bandwidth: Some(bandwidth),
            source: PopulationSource::Library {
                stocks: by_stock.len(),
                lots: lots.len(),
                sheets: all.len(),
                spots: all.iter().map(|s| s.spots.len()).sum(),
                instruments: instruments.len(),
                left_out_sheets,
            },
            validation: None,
        };
        let within = add3(&population.spot.used, &population.sheet.used);
        if crate::analysis::linalg::cholesky(&restrict(&within, &[0, 1, 2])).is_none() {
            return Err(EvidenceError::Degenerate {
                what: "within-stock",
            });
        }
        Ok(population)
    }

    /// The demonstration population: the eight reference papers of Akao et al. Table 6 as
    /// stocks, their neighbours assumed [`DEMONSTRATION_BETWEEN_RELATIVE_SD`] away, sheets
    /// and spots assumed to vary by [`DEMONSTRATION_SHEET_RELATIVE_SD`] and
    /// [`DEMONSTRATION_SPOT_RELATIVE_SD`]. Every figure is assumed: for demonstration, not
    /// evidence.
    pub fn demonstration() -> Population {
        let stocks = REFERENCES
            .iter()
            .map(|r| StockMean {
                name: r.name.to_string(),
                mean: [
                    r.params.sigma_deg.ln(),
                    r.params.rho_s.ln(),
                    r.params.rho_d.ln(),
                ],
                covariance: [[0.0; 3]; 3],
                sheets: 0,
            })
            .collect();
        let assumed = |sd: &[f64; 3]| Component {
            estimate: log_variances(sd),
            dof: 0,
            used: log_variances(sd),
        };
        let mut population = Population {
            stocks,
            spot: assumed(&DEMONSTRATION_SPOT_RELATIVE_SD),
            sheet: assumed(&DEMONSTRATION_SHEET_RELATIVE_SD),
            kernel: log_variances(&DEMONSTRATION_BETWEEN_RELATIVE_SD),
            bandwidth: None,
            source: PopulationSource::Demonstration,
            validation: None,
        };
        population.validation = super::validation::validate_demonstration(&population);
        population
    }

    /// The number of stocks.
    pub fn len(&self) -> usize {
        self.stocks.len()
    }

    /// Whether it has no stocks.
    pub fn is_empty(&self) -> bool {
        self.stocks.is_empty()
    }

    /// Whether it is the demonstration population.
    pub(crate) fn is_demonstration(&self) -> bool {
        self.source == PopulationSource::Demonstration
    }

    /// SHA-256 (hex) of its JSON: what a report names it by.
    pub fn identity(&self) -> String {
        sha256_of_json(self)
    }
}

/// SHA-256 (hex) of the library sheets a population is made from: what a validation is
/// recorded under, so the same contents find it and changed contents do not.
pub fn contents_identity(sheets: &[LibrarySheet]) -> String {
    sha256_of_json(sheets)
}

/// SHA-256 of a value's JSON, written into the hash as it is made: the JSON of a large
/// library's sheets is hundreds of megabytes that need never be held at once.
fn sha256_of_json<T: Serialize + ?Sized>(value: &T) -> String {
    let mut hashing = Sha256Writer::default();
    // A value that cannot be written as JSON hashes as the empty document, as before.
    if serde_json::to_writer(std::io::BufWriter::new(&mut hashing), value).is_err() {
        hashing = Sha256Writer::default();
    }
    hashing.hex()
}

/// A writer that hashes what is written to it (SHA-256) and keeps nothing else: for a
/// digest of a stream too large to hold (a library's sheets, its export).
#[derive(Default)]
pub struct Sha256Writer(sha2::Sha256);

impl Sha256Writer {
    /// The digest of everything written, lowercase hex.
    pub fn hex(self) -> String {
        use sha2::Digest;
        self.0
            .finalize()
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect()
    }
}

impl std::io::Write for Sha256Writer {
    fn write(&mut self, bytes: &[u8]) -> std::io::Result<usize> {
        sha2::Digest::update(&mut self.0, bytes);
        Ok(bytes.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

/// Spots about their sheet's mean: the pooled scatter and its upper bound.
fn spot_level(all: &[&LogSheet]) -> Component {
    let spot_dof: usize = all.iter().map(|s| s.spots.len() - 1).sum();
    let spot_rows: Vec<[f64; 3]> = all
        .iter()
        .flat_map(|s| {
            s.spots
                .iter()
                .map(move |p| std::array::from_fn(|i| p[i] - s.mean[i]))
        })
        .collect();
    let spot_estimate = scatter(spot_rows.iter(), &[0.0; 3], spot_dof);
    Component {
        estimate: spot_estimate,
        dof: spot_dof,
        used: positive_definite_or_diagonal(with_variances(
            &spot_estimate,
            diagonal(&spot_estimate).map(|v| {
                if spot_dof == 0 {
                    0.0
                } else {
                    upper_variance(v, spot_dof)
                }
            }),
        )),
    }
}

/// Sheets' means about their stock's mean, from stocks of two or more sheets, less what
/// their spots' scatter explains. Without a sheet of two spots the two levels cannot be
/// told apart: all of the sheets' scatter is then the sheet level, which does not average
/// over a questioned sheet's spots (the cautious side). Without a stock of two sheets the
/// sheet level is taken equal to the spot level (not measured: `dof` 0).
fn sheet_level(
    by_stock: &BTreeMap<&str, Vec<LogSheet>>,
    spot: &Component,
) -> Result<Component, EvidenceError> {
    let repeated: Vec<&Vec<LogSheet>> = by_stock.values().filter(|s| s.len() >= 2).collect();
    let sheet_dof: usize = repeated.iter().map(|s| s.len() - 1).sum();
    if spot.dof == 0 && sheet_dof == 0 {
        return Err(EvidenceError::NoWithinStockVariation);
    }
    if sheet_dof == 0 {
        return Ok(Component {
            estimate: [[0.0; 3]; 3],
            dof: 0,
            used: spot.used,
        });
    }
    let mut rows = Vec::new();
    let mut inverse_n = Vec::new();
    for sheets in &repeated {
        let means: Vec<[f64; 3]> = sheets.iter().map(|s| s.mean).collect();
        let stock_mean = mean_of(&means);
        rows.extend(
            means
                .iter()
                .map(|m| -> [f64; 3] { std::array::from_fn(|i| m[i] - stock_mean[i]) }),
        );
        inverse_n.extend(sheets.iter().map(|s| 1.0 / s.spots.len() as f64));
    }
    let of_means = scatter(rows.iter(), &[0.0; 3], sheet_dof);
    let c = inverse_n.iter().sum::<f64>() / inverse_n.len() as f64;
    let spot_estimate = &spot.estimate;
    Ok(Component {
        estimate: with_variances(
            &of_means,
            std::array::from_fn(|i| of_means[i][i] - c * spot_estimate[i][i]),
        ),
        dof: sheet_dof,
        used: positive_definite_or_diagonal(with_variances(
            &of_means,
            std::array::from_fn(|i| {
                upper_variance(of_means[i][i], sheet_dof) - c * spot_estimate[i][i]
            }),
        )),
    })
}

/// The kernel h²·B and h: B the spread of the stock means less their own estimation
/// noise (each variance floored at 1 % of the raw spread's), h maximising the
/// leave-one-stock-out log likelihood of the stock means on a grid in (0, 1]. `None`
/// when no h gives a finite likelihood.
/// Stocks whose leave-one-out density [`choose_kernel`] sums: all of them up to this many;
/// beyond, this many evenly spread over the library (each still against every other
/// stock). The likelihood is a mean over stocks, which so many estimate well, and summing
/// it over all of 20,000 stocks (4·10⁸ pairs for each of 40 bandwidths) took many minutes.
pub(crate) const LOO_STOCKS: usize = 1_000;

/// The stocks [`choose_kernel`]'s likelihood is summed over (see [`LOO_STOCKS`]).
fn held_out_stocks(n: usize) -> Vec<usize> {
    if n <= LOO_STOCKS {
        return (0..n).collect();
    }
    (0..LOO_STOCKS).map(|k| k * n / LOO_STOCKS).collect()
}

/// Most distinct covariances [`covariance_groups`] keeps a table for.
const MAX_COVARIANCE_GROUPS: usize = 32;

/// Each covariance's index among the distinct ones, and those; `None` when there are more
/// than [`MAX_COVARIANCE_GROUPS`].
fn covariance_groups(covariances: &[Small]) -> Option<(Vec<usize>, Vec<Small>)> {
    let mut distinct: Vec<Small> = Vec::new();
    let mut of = Vec::with_capacity(covariances.len());
    for c in covariances {
        let k = match distinct.iter().position(|d| d == c) {
            Some(k) => k,
            None => {
                if distinct.len() == MAX_COVARIANCE_GROUPS {
                    return None;
                }
                distinct.push(*c);
                distinct.len() - 1
            }
        };
        of.push(k);
    }
    Some((of, distinct))
}

fn choose_kernel(stocks: &[StockMean]) -> Option<(Cov3, f64)> {
    let means: Vec<[f64; 3]> = stocks.iter().map(|s| s.mean).collect();
    let grand = mean_of(&means);
    let spread = scatter(means.iter(), &grand, means.len() - 1);
    let noise = scale3(
        &stocks
            .iter()
            .fold([[0.0; 3]; 3], |acc, s| add3(&acc, &s.covariance)),
        1.0 / stocks.len() as f64,
    );
    let shape = with_variances(
        &spread,
        std::array::from_fn(|i| (spread[i][i] - noise[i][i]).max(0.01 * spread[i][i])),
    );
    let all = [0, 1, 2];
    let covariances: Vec<Small> = stocks
        .iter()
        .map(|s| Small::restrict(&s.covariance, &all))
        .collect();
    // Stocks of the same sheets and spots have the same covariance: the covariance of a
    // pair, (K + E_j) + E_s, is then one of few, each factorised once per h instead of
    // once per pair (the same operations on the same numbers, so the same result).
    let groups = covariance_groups(&covariances);
    let held_out = held_out_stocks(stocks.len());
    let loo = |h: f64, terms: &mut Vec<f64>| -> Option<f64> {
        let kernel = Small::restrict(&scale3(&shape, h * h), &all);
        let factors: Option<(Vec<Option<Factor>>, usize)> = groups.as_ref().map(|(_, distinct)| {
            let g = distinct.len();
            let table = (0..g * g)
                .map(|k| {
                    kernel
                        .plus(&distinct[k / g])
                        .plus(&distinct[k % g])
                        .factor()
                })
                .collect();
            (table, g)
        });
        let mut total = 0.0;
        for &j in &held_out {
            let sj = &stocks[j];
            let around_j = kernel.plus(&covariances[j]);
            terms.clear();
            for (s, ss) in stocks.iter().enumerate() {
                if s == j {
                    continue;
                }
                let factor = match (&factors, &groups) {
                    (Some((table, g)), Some((of, _))) => table[of[j] * g + of[s]],
                    _ => around_j.plus(&covariances[s]).factor(),
                };
                terms.push(factor?.log_density(&sj.mean, &ss.mean));
            }
            total += log_mean_exp(terms);
        }
        total.is_finite().then_some(total)
    };
    // h from 1 down to about 0.002 in steps of 15 %, each h's likelihood on its own: the
    // grid is shared among the machine's cores (the choice below is made in the grid's
    // order, so the result does not depend on how many there are).
    let grid: Vec<f64> = (0..40).map(|k| 0.85f64.powi(k)).collect();
    let threads = std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .min(grid.len());
    let likelihoods: Vec<Option<f64>> = std::thread::scope(|scope| {
        let workers: Vec<_> = (0..threads)
            .map(|t| {
                let (grid, loo) = (&grid, &loo);
                scope.spawn(move || {
                    let mut terms = Vec::with_capacity(stocks.len());
                    (t..grid.len())
                        .step_by(threads)
                        .map(|k| (k, loo(grid[k], &mut terms)))
                        .collect::<Vec<_>>()
                })
            })
            .collect();
        let mut out = vec![None; grid.len()];
        for worker in workers {
            // A worker that panicked leaves its h without a likelihood.
            for (k, l) in worker.join().unwrap_or_default() {
                out[k] = l;
            }
        }
        out
    });
    let mut best: Option<(f64, f64)> = None;
    for (&h, l) in grid.iter().zip(likelihoods) {
        if let Some(l) = l
            && best.is_none_or(|(_, b)| l > b)
        {
            best = Some((h, l));
        }
    }
    let (h, _) = best?;
    Some((scale3(&shape, h * h), h))
}
