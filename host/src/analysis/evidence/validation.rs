//! A population's validation: same- and different-stock pairs of its own library, each
//! weighed against a population that holds neither pair's stock, then a calibrator, the
//! empirical bounds of what those pairs support, and the figures a court reads (after the
//! Netherlands Forensic Institute's `lir`: Cllr, Cllr_min, Cllr_cal, ELUB; Vergeer et al.
//! 2016 for the bounds).
//!
//! - **Folds by stock.** The stocks are dealt into folds (each its own up to twelve
//!   stocks, else five); a pair whose stocks lie in folds f and g is weighed against the
//!   population of the other folds' stocks.
//!   Leaving out only the first stock would keep the second in the population, which makes
//!   a different-stock pair's second sheet look common and its ratio too small.
//! - **Calibrator: logistic** (log10 LR_cal = a + b·log10 LR_raw, classes weighted
//!   equally, shrunk lightly towards the identity). The model's ratio is already a
//!   likelihood ratio, so a monotone map of two parameters is all it should need; PAV's
//!   step function overfits validations of a few hundred same-stock pairs and gives 0 and
//!   ∞ at its ends (it is used for Cllr_min, where that is the point). Cross-validated:
//!   the pairs of a fold are calibrated by a calibrator fitted on pairs of the others.
//! - **Bounds: ELUB** on the cross-validated calibrated ratios, with one misleading pair of
//!   each kind added (so a validation of N pairs never supports more than about log10 N).
use super::density::{Cov3, add3};
use super::population::log_variances;
use super::population::{LibrarySheet, Population};
use super::{EvidenceError, Sheet, Spot, raw_log10_lr};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Folds the stocks are dealt into, when there are more stocks than
/// [`ONE_FOLD_PER_STOCK_UP_TO`].
pub(crate) const MAX_FOLDS: usize = 5;
/// Up to this many stocks, every stock is its own fold (each pair is weighed against the
/// population without exactly its two stocks).
pub(crate) const ONE_FOLD_PER_STOCK_UP_TO: usize = 12;
/// Fewest pairs of each kind a validation is made from.
pub(crate) const MIN_PAIRS: usize = 10;
/// Most densities (pairs of sheets × 3 × stocks) a validation made for one search or
/// comparison may evaluate: about ten seconds' worth. A validation weighs every pair of
/// sheets, so its time grows with the cube of the library: 2,000 stocks of five sheets
/// would take days.
pub(crate) const MAX_VALIDATION_EVALUATIONS: f64 = 1e9;
/// The grid step of the ELUB search, log10.
const ELUB_STEP: f64 = 0.01;
/// Raw log10 LRs are clipped to ± this many decades before the calibrator is fitted.
const CALIBRATION_CLIP: f64 = 9.0;
/// Weight of the calibrator's pull towards the identity (slope 1, intercept 0), against a
/// mean log loss of order 1.
const CALIBRATOR_SHRINKAGE: f64 = 1e-3;

/// log10 LR_cal = intercept + slope · log10 LR_raw.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Calibrator {
    /// b.
    pub(crate) slope: f64,
    /// a, log10.
    pub(crate) intercept: f64,
}

impl Calibrator {
    /// The identity (no calibration).
    pub(crate) const IDENTITY: Calibrator = Calibrator {
        slope: 1.0,
        intercept: 0.0,
    };

    /// A raw log10 LR calibrated.
    pub fn apply(&self, raw_log10_lr: f64) -> f64 {
        self.intercept + self.slope * raw_log10_lr
    }

    /// Fitted to same- and different-stock raw log10 LRs by logistic regression with the
    /// two classes weighted equally (so the fitted log odds are a log LR), by Newton's
    /// method. The identity when a class is empty.
    pub fn fit(same: &[f64], different: &[f64]) -> Calibrator {
        if same.is_empty() || different.is_empty() {
            return Calibrator::IDENTITY;
        }
        let ln10 = std::f64::consts::LN_10;
        // Ratios beyond ±CALIBRATION_CLIP decades say nothing more about the map's slope
        // and would let a nearly separable validation drive it to infinity.
        let clip = |x: f64| x.clamp(-CALIBRATION_CLIP, CALIBRATION_CLIP) * ln10;
        let points: Vec<(f64, f64, f64)> = same
            .iter()
            .map(|&x| (clip(x), 1.0, 1.0 / same.len() as f64))
            .chain(
                different
                    .iter()
                    .map(|&x| (clip(x), 0.0, 1.0 / different.len() as f64)),
            )
            .filter(|(x, _, _)| x.is_finite())
            .collect();
        let lambda = CALIBRATOR_SHRINKAGE;
        // Σ w·(log loss) + λ((β−1)² + α²), in natural logs: ln LR = α + β·x.
        let objective = |alpha: f64, beta: f64| -> f64 {
            let softplus = |t: f64| if t > 30.0 { t } else { t.exp().ln_1p() };
            points
                .iter()
                .map(|&(x, y, w)| {
                    let t = alpha + beta * x;
                    w * if y > 0.5 { softplus(-t) } else { softplus(t) }
                })
                .sum::<f64>()
                + lambda * ((beta - 1.0).powi(2) + alpha * alpha)
        };
        let (mut alpha, mut beta) = (0.0f64, 1.0f64);
        let mut value = objective(alpha, beta);
        for _ in 0..200 {
            let (mut ga, mut gb) = (2.0 * lambda * alpha, 2.0 * lambda * (beta - 1.0));
            let (mut haa, mut hab, mut hbb) = (2.0 * lambda, 0.0, 2.0 * lambda);
            for &(x, y, w) in &points {
                let p = 1.0 / (1.0 + (-(alpha + beta * x)).exp());
                let r = w * (p - y);
                ga += r;
                gb += r * x;
                let s = w * p * (1.0 - p);
                haa += s;
                hab += s * x;
                hbb += s * x * x;
            }
            let det = haa * hbb - hab * hab;
            if !(det > 0.0 && det.is_finite()) {
                break;
            }
            let da = (hbb * ga - hab * gb) / det;
            let db = (haa * gb - hab * ga) / det;
            // Damped: halve the Newton step until the objective does not rise.
            let mut step = 1.0;
            let mut moved = false;
            while step > 1e-6 {
                let (a, b) = (alpha - step * da, beta - step * db);
                let v = objective(a, b);
                if v <= value {
                    (alpha, beta, value) = (a, b, v);
                    moved = true;
                    break;
                }
                step *= 0.5;
            }
            if !moved || (step * da).abs().max((step * db).abs()) < 1e-10 {
                break;
            }
        }
        if !(alpha.is_finite() && beta.is_finite()) {
            return Calibrator::IDENTITY;
        }
        Calibrator {
            slope: beta,
            intercept: alpha / ln10,
        }
    }
}

/// Cllr (bits) of same- and different-stock log10 LRs: 0 for a perfect system, 1 for one
/// that always says LR = 1.
pub fn cllr(same: &[f64], different: &[f64]) -> f64 {
    let ln10 = std::f64::consts::LN_10;
    // log2(1 + 10^-x) without overflow.
    let softplus_bits = |x: f64| -> f64 {
        let t = -x * ln10;
        let nat = if t > 30.0 { t } else { t.exp().ln_1p() };
        nat / std::f64::consts::LN_2
    };
    let s = same.iter().map(|&x| softplus_bits(x)).sum::<f64>() / same.len().max(1) as f64;
    let d =
        different.iter().map(|&x| softplus_bits(-x)).sum::<f64>() / different.len().max(1) as f64;
    0.5 * (s + d)
}

/// The log10 LRs after the best monotone recalibration on themselves (pool-adjacent
/// violators, classes weighted equally, tied values pooled): what Cllr_min is made of.
pub(crate) fn pav(same: &[f64], different: &[f64]) -> (Vec<f64>, Vec<f64>) {
    let mut scored: Vec<(f64, bool)> = same
        .iter()
        .map(|&x| (x, true))
        .chain(different.iter().map(|&x| (x, false)))
        .collect();
    scored.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (ws, wd) = (
        1.0 / same.len().max(1) as f64,
        1.0 / different.len().max(1) as f64,
    );
    // Blocks of (weighted same, weighted different, count); equal scores start as one.
    let mut blocks: Vec<(f64, f64, usize)> = Vec::new();
    let mut k = 0;
    while k < scored.len() {
        let mut block = (0.0, 0.0, 0);
        let x = scored[k].0;
        while k < scored.len() && scored[k].0 == x {
            if scored[k].1 {
                block.0 += ws
            } else {
                block.1 += wd
            }
            block.2 += 1;
            k += 1;
        }
        blocks.push(block);
        while blocks.len() >= 2 {
            let (s2, d2, n2) = blocks[blocks.len() - 1];
            let (s1, d1, n1) = blocks[blocks.len() - 2];
            // Merge while the earlier block's same-share is higher.
            if s1 * (s2 + d2) > s2 * (s1 + d1) {
                blocks.truncate(blocks.len() - 2);
                blocks.push((s1 + s2, d1 + d2, n1 + n2));
            } else {
                break;
            }
        }
    }
    let (mut out_same, mut out_different) = (Vec::new(), Vec::new());
    let mut k = 0;
    for (s, d, n) in blocks {
        let log10_lr = (s / d).log10();
        for _ in 0..n {
            if scored[k].1 {
                out_same.push(log10_lr)
            } else {
                out_different.push(log10_lr)
            }
            k += 1;
        }
    }
    (out_same, out_different)
}

/// Cllr after the best monotone recalibration of the same values: what remains is their
/// discrimination, the rest of Cllr their calibration.
pub fn cllr_min(same: &[f64], different: &[f64]) -> f64 {
    let (s, d) = pav(same, different);
    cllr(&s, &d)
}

/// The empirical lower and upper bounds (ELUB, Vergeer et al. 2016) of log10 LR that
/// same- and different-stock log10 LRs support: the widest range of thresholds θ about 1
/// at which deciding by these ratios is at least as good as deciding by LR = 1, with one
/// misleading ratio of each kind added so that a bound never exceeds about log10 of the
/// pairs behind it.
pub(crate) fn elub(same: &[f64], different: &[f64]) -> (f64, f64) {
    let clip = |v: &f64| v.clamp(-9.0, 9.0);
    let same: Vec<f64> = same.iter().map(clip).collect();
    let different: Vec<f64> = different.iter().map(clip).collect();
    let (n1, n2) = (same.len() as f64, different.len() as f64);
    if same.is_empty() || different.is_empty() {
        return (0.0, 0.0);
    }
    let min = same
        .iter()
        .chain(&different)
        .copied()
        .fold(f64::INFINITY, f64::min);
    let max = same
        .iter()
        .chain(&different)
        .copied()
        .fold(f64::NEG_INFINITY, f64::max);
    let lo = min.max(-(n1 + 1.0).log10());
    let hi = max.min((n2 + 1.0).log10());
    let k_lo = ((lo / ELUB_STEP).floor() as i64).min(0);
    let k_hi = ((hi / ELUB_STEP).floor() as i64 + 1).max(0);
    // The system's expected utility at threshold θ = 10^ρ against the neutral min(θ, 1).
    let fails = |rho: f64| -> bool {
        let theta = 10f64.powf(rho);
        let missed = same.iter().filter(|&&x| x <= rho).count() as f64 + 1.0;
        let accepted = different.iter().filter(|&&x| x > rho).count() as f64 + 1.0;
        let system = missed / (n1 + 1.0) + theta * accepted / (n2 + 1.0);
        theta.min(1.0) / system < 1.0
    };
    let grid = |k: i64| k as f64 * ELUB_STEP;
    let lower = (k_lo..=0)
        .rev()
        .find(|&k| fails(grid(k)))
        .map_or(grid(k_lo), |k| grid(k) + ELUB_STEP);
    let upper = (0..=k_hi)
        .find(|&k| fails(grid(k)))
        .map_or(grid(k_hi), |k| grid(k) - ELUB_STEP);
    (lower.min(0.0), upper.max(0.0))
}

/// One decade of reported log10 LR, with the pairs reported in it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CalibrationBin {
    /// The decade's lower edge (log10 LR in [from, from + 1)).
    pub from: f64,
    /// Same-stock pairs reported in it.
    pub same: usize,
    /// Different-stock pairs reported in it.
    pub different: usize,
    /// log10 of (same/all same) ÷ (different/all different): the ratio the decade's reports
    /// actually had; `None` when a kind is absent.
    pub(crate) observed_log10_lr: Option<f64>,
}

/// The decades of `same` and `different` (reported log10 LRs).
pub(crate) fn calibration_bins(same: &[f64], different: &[f64]) -> Vec<CalibrationBin> {
    let mut bins: BTreeMap<i64, (usize, usize)> = BTreeMap::new();
    for &x in same {
        bins.entry(x.floor() as i64).or_default().0 += 1;
    }
    for &x in different {
        bins.entry(x.floor() as i64).or_default().1 += 1;
    }
    let (n1, n2) = (same.len().max(1) as f64, different.len().max(1) as f64);
    bins.into_iter()
        .map(|(from, (s, d))| CalibrationBin {
            from: from as f64,
            same: s,
            different: d,
            observed_log10_lr: (s > 0 && d > 0)
                .then(|| ((s as f64 / n1) / (d as f64 / n2)).log10()),
        })
        .collect()
}

/// What a population's validation found.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Validation {
    /// Same-stock pairs.
    pub(crate) same_pairs: usize,
    /// Different-stock pairs.
    pub(crate) different_pairs: usize,
    /// Folds the stocks were dealt into.
    pub(crate) folds: usize,
    /// The calibrator fitted on every pair (what comparisons use).
    pub calibrator: Calibrator,
    /// ELUB bounds of log10 LR (what comparisons are held within).
    pub bounds: (f64, f64),
    /// Cllr of the reported (cross-validated, calibrated, bounded) ratios.
    pub cllr: f64,
    /// Cllr_min: the same ratios' discrimination.
    pub cllr_min: f64,
    /// Cllr − Cllr_min: their calibration loss.
    pub(crate) cllr_cal: f64,
    /// Cllr of the model's raw ratios.
    pub cllr_raw: f64,
    /// Same-stock pairs reported below LR 1, and below 1/100.
    pub(crate) same_below: (usize, usize),
    /// Different-stock pairs reported above LR 1, and above 100.
    pub(crate) different_above: (usize, usize),
    /// The reported decades.
    pub bins: Vec<CalibrationBin>,
    /// Each same-stock pair's reported log10 LR (for the plots; not stored).
    #[serde(skip)]
    pub same: Vec<f64>,
    /// Each different-stock pair's reported log10 LR (for the plots; not stored).
    #[serde(skip)]
    pub different: Vec<f64>,
    /// Each same-stock pair's raw log10 LR (not stored).
    #[serde(skip)]
    pub(crate) same_raw: Vec<f64>,
    /// Each different-stock pair's raw log10 LR (not stored).
    #[serde(skip)]
    pub(crate) different_raw: Vec<f64>,
}

/// One weighed pair of the validation.
struct Scored {
    same: bool,
    /// The folds of its two stocks.
    folds: (usize, usize),
    raw: f64,
}

impl Validation {
    /// The validation made of `raw` pairs, each with its folds: calibrated fold by fold,
    /// bounded, and measured.
    fn of_pairs(pairs: &[Scored], folds: usize) -> Result<Validation, EvidenceError> {
        let (same_n, different_n) = (
            pairs.iter().filter(|p| p.same).count(),
            pairs.iter().filter(|p| !p.same).count(),
        );
        if same_n < MIN_PAIRS || different_n < MIN_PAIRS {
            return Err(EvidenceError::TooFewPairs {
                needed: MIN_PAIRS,
                same: same_n,
                different: different_n,
            });
        }
        let split = |pairs: &mut dyn Iterator<Item = &Scored>| -> (Vec<f64>, Vec<f64>) {
            let (mut s, mut d) = (Vec::new(), Vec::new());
            for p in pairs {
                if p.same { s.push(p.raw) } else { d.push(p.raw) }
            }
            (s, d)
        };
        // Each pair calibrated by a calibrator that saw neither of its folds: one per pair
        // of folds, fitted once.
        let mut calibrators: BTreeMap<(usize, usize), Calibrator> = BTreeMap::new();
        let calibrated: Vec<f64> = pairs
            .iter()
            .map(|p| {
                let calibrator = calibrators.entry(p.folds).or_insert_with(|| {
                    let (s, d) = split(&mut pairs.iter().filter(|q| {
                        folds < 2
                            || (q.folds.0 != p.folds.0
                                && q.folds.1 != p.folds.0
                                && q.folds.0 != p.folds.1
                                && q.folds.1 != p.folds.1)
                    }));
                    Calibrator::fit(&s, &d)
                });
                calibrator.apply(p.raw)
            })
            .collect();
        let (mut cs, mut cd) = (Vec::new(), Vec::new());
        for (p, c) in pairs.iter().zip(&calibrated) {
            if p.same { cs.push(*c) } else { cd.push(*c) }
        }
        let bounds = elub(&cs, &cd);
        let bound = |v: &f64| v.clamp(bounds.0, bounds.1);
        let same: Vec<f64> = cs.iter().map(bound).collect();
        let different: Vec<f64> = cd.iter().map(bound).collect();
        let (same_raw, different_raw) = split(&mut pairs.iter());
        let cllr_all = cllr(&same, &different);
        let cllr_min = cllr_min(&same, &different);
        Ok(Validation {
            same_pairs: same_n,
            different_pairs: different_n,
            folds,
            calibrator: Calibrator::fit(&same_raw, &different_raw),
            bounds,
            cllr: cllr_all,
            cllr_min,
            cllr_cal: cllr_all - cllr_min,
            cllr_raw: cllr(&same_raw, &different_raw),
            same_below: (
                same.iter().filter(|&&x| x < 0.0).count(),
                same.iter().filter(|&&x| x < -2.0).count(),
            ),
            different_above: (
                different.iter().filter(|&&x| x > 0.0).count(),
                different.iter().filter(|&&x| x > 2.0).count(),
            ),
            bins: calibration_bins(&same, &different),
            same,
            different,
            same_raw,
            different_raw,
        })
    }
}

/// The population of `sheets` with its validation: every pair of sheets weighed against
/// the population of the stocks outside both sheets' folds.
pub fn validate(sheets: &[LibrarySheet]) -> Result<Population, EvidenceError> {
    let mut population = Population::from_library(sheets)?;
    // Only sheets the population could use (every spot determined σ, ρs and ρd).
    let usable: Vec<&LibrarySheet> = sheets
        .iter()
        .filter(|s| !s.sheet.spots.is_empty() && s.sheet.determined().len() == 3)
        .collect();
    let names: Vec<&str> = population.stocks.iter().map(|s| s.name.as_str()).collect();
    let needed = super::population::MIN_STOCKS + 2;
    if names.len() < needed {
        return Err(EvidenceError::TooFewStocksToValidate {
            needed,
            found: names.len(),
        });
    }
    let folds = if names.len() <= ONE_FOLD_PER_STOCK_UP_TO {
        names.len()
    } else {
        MAX_FOLDS
    };
    let fold_of = |stock: &str| names.iter().position(|n| *n == stock).unwrap_or(0) % folds;
    // One population per pair of folds (f ≤ g), from the stocks of the others.
    let mut held_out: BTreeMap<(usize, usize), Population> = BTreeMap::new();
    for f in 0..folds {
        for g in f..folds {
            let rest: Vec<LibrarySheet> = usable
                .iter()
                .filter(|s| {
                    let k = fold_of(&s.stock);
                    k != f && k != g
                })
                .map(|s| (*s).clone())
                .collect();
            held_out.insert((f, g), Population::from_library(&rest)?);
        }
    }
    let mut pairs = Vec::new();
    for (i, a) in usable.iter().enumerate() {
        for b in &usable[i + 1..] {
            let (fa, fb) = (fold_of(&a.stock), fold_of(&b.stock));
            let key = (fa.min(fb), fa.max(fb));
            let Some(rest) = held_out.get(&key) else {
                continue;
            };
            pairs.push(Scored {
                same: a.stock == b.stock,
                folds: key,
                raw: raw_log10_lr(&a.sheet, &b.sheet, rest),
            });
        }
    }
    population.validation = Some(Validation::of_pairs(&pairs, folds)?);
    Ok(population)
}

/// The population of a library's sheets, validated when the library allows it; when it
/// does not (too few stocks, or too few with two sheets, to hold some out), the population
/// without validation and why.
///
/// A library too large to validate within a search or a comparison (more than
/// [`MAX_VALIDATION_EVALUATIONS`]) is not validated there: its population is used
/// unvalidated, saying why, rather than the search taking hours.
pub fn validate_or_explain(
    sheets: &[LibrarySheet],
) -> Result<(Population, Option<EvidenceError>), EvidenceError> {
    let usable: Vec<&LibrarySheet> = sheets
        .iter()
        .filter(|s| !s.sheet.spots.is_empty() && s.sheet.determined().len() == 3)
        .collect();
    let stocks = usable
        .iter()
        .map(|s| s.stock.as_str())
        .collect::<std::collections::BTreeSet<_>>()
        .len();
    let pairs = usable.len() * usable.len().saturating_sub(1) / 2;
    if pairs as f64 * 3.0 * stocks as f64 > MAX_VALIDATION_EVALUATIONS {
        return Ok((
            Population::from_library(sheets)?,
            Some(EvidenceError::TooLargeToValidate { pairs, stocks }),
        ));
    }
    match validate(sheets) {
        Ok(p) => Ok((p, None)),
        Err(e) => Ok((Population::from_library(sheets)?, Some(e))),
    }
}

/// How the demonstration population is validated: sheets drawn from its own assumptions
/// (stocks about each reference paper, sheets, spots, a fit's 0.5 % noise), weighed
/// against it. It shows what the assumptions imply, nothing about paper.
pub(crate) fn validate_demonstration(population: &Population) -> Option<Validation> {
    use rand::SeedableRng;
    use rand_distr::{Distribution, StandardNormal};
    const STOCKS_PER_PAPER: usize = 4;
    const SHEETS: usize = 3;
    const SPOTS: usize = 3;
    const FIT_RELATIVE_SD: f64 = 0.005;
    let mut rng = rand_chacha::ChaCha12Rng::seed_from_u64(0xde_40);
    let mut normal = |cov: &Cov3| -> [f64; 3] {
        // Diagonal covariances only (the demonstration's are).
        std::array::from_fn(|i| {
            let z: f64 = StandardNormal.sample(&mut rng);
            z * cov[i][i].sqrt()
        })
    };
    let fit = log_variances(&[FIT_RELATIVE_SD; 3]);
    let mut sheets: Vec<(usize, Sheet)> = Vec::new();
    let mut stock = 0;
    for paper in &population.stocks {
        for _ in 0..STOCKS_PER_PAPER {
            let offset = normal(&population.kernel);
            let mean: [f64; 3] = std::array::from_fn(|i| paper.mean[i] + offset[i]);
            for _ in 0..SHEETS {
                let sheet_offset = normal(&population.sheet.used);
                let spots = (0..SPOTS)
                    .map(|_| {
                        let e = normal(&add3(&population.spot.used, &fit));
                        let values: [f64; 3] =
                            std::array::from_fn(|i| (mean[i] + sheet_offset[i] + e[i]).exp());
                        Spot {
                            values: values.map(Some),
                            covariance: std::array::from_fn(|r| {
                                std::array::from_fn(|c| {
                                    if r == c {
                                        (values[r] * FIT_RELATIVE_SD).powi(2)
                                    } else {
                                        0.0
                                    }
                                })
                            }),
                        }
                    })
                    .collect();
                sheets.push((stock, Sheet { spots }));
            }
            stock += 1;
        }
    }
    let mut pairs = Vec::new();
    for (i, (sa, a)) in sheets.iter().enumerate() {
        for (sb, b) in &sheets[i + 1..] {
            pairs.push(Scored {
                same: sa == sb,
                folds: (0, 0),
                raw: raw_log10_lr(a, b, population),
            });
        }
    }
    Validation::of_pairs(&pairs, 1).ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn elub_reproduces_the_worked_example() {
        // H1 {0.5, 1, 1.5, 2, 3}, H2 {−3, −2, −1.5, −1, 0.2}: bounds ±0.60 (computed by
        // hand from Vergeer et al.'s criterion with one misleading pair of each kind).
        let (lo, hi) = elub(&[0.5, 1.0, 1.5, 2.0, 3.0], &[-3.0, -2.0, -1.5, -1.0, 0.2]);
        assert!((hi - 0.60).abs() < 1e-9, "{hi}");
        assert!((lo + 0.60).abs() < 1e-9, "{lo}");
        // Perfectly separated, three each: ±0.47 (θ ≤ 3).
        let (lo, hi) = elub(&[1.0, 2.0, 3.0], &[-1.0, -2.0, -3.0]);
        assert!(
            (hi - 0.47).abs() < 1e-9 && (lo + 0.47).abs() < 1e-9,
            "{lo} {hi}"
        );
    }

    #[test]
    fn elub_grows_with_the_pairs_behind_it_and_never_past_log10_n() {
        let same: Vec<f64> = (0..1000).map(|k| 3.0 + (k % 7) as f64).collect();
        let different: Vec<f64> = (0..1000).map(|k| -3.0 - (k % 7) as f64).collect();
        let (lo, hi) = elub(&same, &different);
        assert!(hi <= 1001f64.log10() + 1e-9 && hi > 2.5, "{hi}");
        assert!(lo >= -1001f64.log10() - 1e-9 && lo < -2.5, "{lo}");
        let (lo10, hi10) = elub(&same[..10], &different[..10]);
        assert!(hi10 < hi && lo10 > lo);
    }

    #[test]
    fn cllr_is_zero_for_a_perfect_system_one_for_an_uninformative_one_and_pav_never_worse() {
        assert_eq!(cllr(&[0.0; 4], &[0.0; 4]), 1.0);
        assert!(cllr(&[30.0], &[-30.0]) < 1e-9);
        let same = [2.0, -1.0, 3.0, 0.5];
        let different = [-2.0, 1.5, -0.5, -4.0];
        assert!(cllr_min(&same, &different) <= cllr(&same, &different) + 1e-12);
        // Tied scores of both kinds are one block: PAV gives them one value.
        let (s, d) = pav(&[1.0, 1.0], &[1.0, 1.0]);
        assert_eq!(s, [0.0, 0.0]);
        assert_eq!(d, [0.0, 0.0]);
    }

    #[test]
    fn the_calibrator_learns_a_scale_and_a_shift() {
        // Raw LRs three times too strong and shifted: same ~ N(+3μ), different ~ N(−3μ).
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let mut rng = rand_chacha::ChaCha12Rng::seed_from_u64(7);
        // A well-calibrated score s has s ~ N(±μ, 2μ/ln10) in log10 (μ in log10).
        let mu = 1.0;
        let sd = (2.0 * mu / std::f64::consts::LN_10).sqrt();
        let h1 = Normal::new(mu, sd).unwrap();
        let h2 = Normal::new(-mu, sd).unwrap();
        let same: Vec<f64> = (0..4000).map(|_| 3.0 * h1.sample(&mut rng) + 1.0).collect();
        let different: Vec<f64> = (0..4000).map(|_| 3.0 * h2.sample(&mut rng) + 1.0).collect();
        let c = Calibrator::fit(&same, &different);
        assert!((c.slope - 1.0 / 3.0).abs() < 0.03, "{c:?}");
        assert!((c.apply(1.0)).abs() < 0.1, "{c:?}");
        let calibrated_same: Vec<f64> = same.iter().map(|&x| c.apply(x)).collect();
        let calibrated_different: Vec<f64> = different.iter().map(|&x| c.apply(x)).collect();
        assert!(
            cllr(&calibrated_same, &calibrated_different) < cllr(&same, &different),
            "calibration lowers Cllr"
        );
        assert_eq!(Calibrator::fit(&[], &[1.0]), Calibrator::IDENTITY);
    }
}
