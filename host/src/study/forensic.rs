//! The forensic validation: a simulated population of paper stocks, sheets of each measured
//! at several spots on the realistic instrument, a library built from some sheets of every
//! stock, and the likelihood ratios of held-out pairs judged as a forensic LR system is:
//! by Cllr (and its minimum after calibration), the rates of misleading evidence and a
//! Tippett plot (the practice of the Netherlands Forensic Institute's `lir` and the ENFSI
//! guideline).
//!
//! Stocks: the eight reference papers of Table 6 and, about each, more stocks of its kind
//! with σ, ρs and ρd drawn log-normally with [`evidence::DEFAULT_BETWEEN_RELATIVE_SD`]
//! (η kept). A spot is one whole simulated session (`--physics real`, `--sheet-variation`
//! [`SPOT_VARIATION_PCT`]: each seed is another spot of the stock); a sheet is its spots.

use crate::analysis::classify::{Class, REFERENCES};
use crate::analysis::evidence::{self, Population, Sheet, Spot};
use crate::analysis::model::{RHO_D, RHO_S, SIGMA};
use crate::instrument::sim::{Physics, SimOptions};
use crate::session::{Policy, PolicyChoice};
use plotters::prelude::*;
use rand::SeedableRng;
use rand_chacha::ChaCha12Rng;
use rand_distr::{Distribution, StandardNormal};
use std::fmt::Write as _;

/// Between-spot variation of every simulated sheet, percent (`--sheet-variation`).
pub const SPOT_VARIATION_PCT: f64 = 3.0;

/// The size of a study.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Design {
    /// Stocks drawn about each reference paper besides the paper itself.
    pub drawn_per_paper: usize,
    /// Sheets of each stock in the library.
    pub library_sheets: usize,
    /// Sheets of each stock held out for the pairs.
    pub held_out_sheets: usize,
    /// Spots per sheet.
    pub spots: usize,
}

impl Design {
    /// The study of docs/FORENSIC.md: 32 stocks, 2 library and 4 held-out sheets of 3 spots.
    pub const FULL: Design = Design { drawn_per_paper: 3, library_sheets: 2, held_out_sheets: 4, spots: 3 };
    /// A small one for the tests.
    pub const SMALL: Design = Design { drawn_per_paper: 3, library_sheets: 2, held_out_sheets: 2, spots: 2 };
}

/// A simulated stock.
#[derive(Clone, Debug, PartialEq)]
pub struct Stock {
    /// Its name (`G`, `G#1`, …).
    pub name: String,
    /// The simulator's sample (`custom:σ,ρs,ρd,η`).
    pub sample: String,
    /// The class of the reference paper it was drawn about.
    pub class: Class,
}

/// The stocks of a study: each reference paper and `drawn_per_paper` drawn about it.
pub fn stocks(design: &Design) -> Vec<Stock> {
    let mut rng = ChaCha12Rng::seed_from_u64(0xf0_2e_75_1c);
    let mut out = Vec::new();
    for r in &REFERENCES {
        let p = r.params;
        for k in 0..=design.drawn_per_paper {
            let mut draw = |x: f64, sd: f64| -> f64 {
                if k == 0 {
                    return x;
                }
                let s2 = (1.0 + sd * sd).ln();
                let z: f64 = StandardNormal.sample(&mut rng);
                x * (s2.sqrt() * z - 0.5 * s2).exp()
            };
            let sd = evidence::DEFAULT_BETWEEN_RELATIVE_SD;
            let (sigma, rho_s, rho_d) = (draw(p.sigma_deg, sd[0]), draw(p.rho_s, sd[1]), draw(p.rho_d, sd[2]));
            let name = if k == 0 { r.name.to_string() } else { format!("{}#{k}", r.name) };
            out.push(Stock { name, sample: format!("custom:{sigma},{rho_s},{rho_d},{}", p.eta), class: r.class });
        }
    }
    out
}

/// One spot of one sheet to measure.
#[derive(Clone, Debug, PartialEq)]
pub struct SpotSpec {
    /// Index into the stocks.
    pub stock: usize,
    /// Sheet number within the stock (library sheets first).
    pub sheet: usize,
    /// Spot number within the sheet.
    pub spot: usize,
    /// The simulator's seed (another spot of the stock, another instrument draw).
    pub seed: u64,
}

/// Every spot of the study.
pub fn plan(design: &Design, stocks: &[Stock]) -> Vec<SpotSpec> {
    let sheets = design.library_sheets + design.held_out_sheets;
    let mut out = Vec::new();
    for stock in 0..stocks.len() {
        for sheet in 0..sheets {
            for spot in 0..design.spots {
                let seed = 1 + ((stock * 1000 + sheet) * 100 + spot) as u64;
                out.push(SpotSpec { stock, sheet, spot, seed });
            }
        }
    }
    out
}

/// Measure one spot: a whole simulated session; `None` when it failed.
pub fn measure(stocks: &[Stock], spec: &SpotSpec) -> Result<Spot, String> {
    let stock = &stocks[spec.stock];
    let options = SimOptions { seed: spec.seed, physics: Physics::Real, sheet_variation: SPOT_VARIATION_PCT, ..SimOptions::default() };
    let run = super::SimulatedRun { sample: &stock.sample, options: &options, policy: Policy::from(PolicyChoice::Adaptive), integration_ms: None };
    let (outcome, _) = super::simulated_session(&run, |session| session)?;
    let fit = &outcome.report.fit;
    let index = [SIGMA, RHO_S, RHO_D];
    Ok(Spot {
        values: index.map(|i| fit.reported(i)),
        covariance: std::array::from_fn(|r| std::array::from_fn(|c| fit.covariance[index[r]][index[c]])),
    })
}

/// A measured sheet of the study.
#[derive(Clone, Debug, PartialEq)]
pub struct MeasuredSheet {
    /// Index into the stocks.
    pub stock: usize,
    /// Sheet number within the stock.
    pub sheet: usize,
    /// Whether it belongs to the library (else held out).
    pub in_library: bool,
    /// Its spots.
    pub measured: Sheet,
}

/// Measure the whole study on `threads` threads.
pub fn measure_all(design: &Design, stocks: &[Stock], threads: usize, progress: &(dyn Fn() + Sync)) -> Result<Vec<MeasuredSheet>, String> {
    let specs = plan(design, stocks);
    let spots = super::parallel(&specs, threads, progress, |spec| measure(stocks, spec));
    if spots.len() != specs.len() {
        return Err("a worker panicked".to_string());
    }
    let mut sheets: Vec<MeasuredSheet> = Vec::new();
    for (spec, spot) in specs.iter().zip(spots) {
        let spot = spot.map_err(|e| format!("{} sheet {} spot {}: {e}", stocks[spec.stock].name, spec.sheet, spec.spot))?;
        match sheets.iter_mut().find(|s| s.stock == spec.stock && s.sheet == spec.sheet) {
            Some(sheet) => sheet.measured.spots.push(spot),
            None => sheets.push(MeasuredSheet { stock: spec.stock, sheet: spec.sheet, in_library: spec.sheet < design.library_sheets, measured: Sheet { spots: vec![spot] } }),
        }
    }
    Ok(sheets)
}

/// One held-out pair and its evidence.
#[derive(Clone, Debug, PartialEq)]
pub struct Pair {
    /// Stock of the first sheet.
    pub stock_a: usize,
    /// Stock of the second.
    pub stock_b: usize,
    /// log10 LR.
    pub log10_lr: f64,
}

/// The library's population and every held-out pair's log10 LR.
pub fn pairs(stocks: &[Stock], sheets: &[MeasuredSheet]) -> Result<(Population, Vec<Pair>), evidence::EvidenceError> {
    let library: Vec<(String, Sheet)> = sheets.iter().filter(|s| s.in_library).map(|s| (stocks[s.stock].name.clone(), s.measured.clone())).collect();
    let population = Population::from_sheets(&library)?;
    let held: Vec<&MeasuredSheet> = sheets.iter().filter(|s| !s.in_library).collect();
    let mut out = Vec::new();
    for (i, a) in held.iter().enumerate() {
        for b in &held[i + 1..] {
            let e = evidence::likelihood_ratio(&a.measured, &b.measured, &population);
            out.push(Pair { stock_a: a.stock, stock_b: b.stock, log10_lr: e.log10_lr });
        }
    }
    Ok((population, out))
}

/// How often a held-out sheet's own stock ranks first among the library's stocks (each
/// stock's library sheets pooled as one sheet), as `gonio library search` ranks them.
pub fn search_rank_one(stocks: &[Stock], sheets: &[MeasuredSheet], population: &Population) -> (usize, usize) {
    let library: Vec<(String, Sheet)> = sheets.iter().filter(|s| s.in_library).map(|s| (stocks[s.stock].name.clone(), s.measured.clone())).collect();
    let held: Vec<&MeasuredSheet> = sheets.iter().filter(|s| !s.in_library).collect();
    let first = held.iter().filter(|s| evidence::rank_stocks(&s.measured, &library, population).first().is_some_and(|r| r.stock == stocks[s.stock].name)).count();
    (first, held.len())
}

/// Cllr: the log-likelihood-ratio cost (bits); 0 for perfect, 1 for an uninformative
/// system that always says LR = 1.
pub fn cllr(same: &[f64], different: &[f64]) -> f64 {
    let ln10 = std::f64::consts::LN_10;
    // log2(1 + 10^-x) without overflow.
    let softplus_bits = |x: f64| -> f64 {
        let t = -x * ln10;
        let nat = if t > 30.0 { t } else { t.exp().ln_1p() };
        nat / std::f64::consts::LN_2
    };
    let s = same.iter().map(|&x| softplus_bits(x)).sum::<f64>() / same.len().max(1) as f64;
    let d = different.iter().map(|&x| softplus_bits(-x)).sum::<f64>() / different.len().max(1) as f64;
    0.5 * (s + d)
}

/// Cllr after the best monotone recalibration of the same scores (pool-adjacent-violators):
/// what remains is the scores' discrimination, the rest of Cllr their calibration.
pub fn cllr_min(same: &[f64], different: &[f64]) -> f64 {
    let mut scored: Vec<(f64, f64)> = same.iter().map(|&x| (x, 1.0)).chain(different.iter().map(|&x| (x, 0.0))).collect();
    scored.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.total_cmp(&b.1)));
    // Blocks of (sum of labels, count), merged while they decrease.
    let mut blocks: Vec<(f64, f64)> = Vec::new();
    for &(_, label) in &scored {
        blocks.push((label, 1.0));
        while blocks.len() >= 2 {
            let (s2, n2) = blocks[blocks.len() - 1];
            let (s1, n1) = blocks[blocks.len() - 2];
            if s1 / n1 > s2 / n2 {
                blocks.pop();
                blocks.pop();
                blocks.push((s1 + s2, n1 + n2));
            } else {
                break;
            }
        }
    }
    let prior_odds = same.len() as f64 / different.len().max(1) as f64;
    let mut calibrated_same = Vec::new();
    let mut calibrated_different = Vec::new();
    let mut k = 0;
    for (sum, count) in blocks {
        let p = sum / count;
        let log10_lr = if p >= 1.0 { f64::INFINITY } else if p <= 0.0 { f64::NEG_INFINITY } else { (p / (1.0 - p) / prior_odds).log10() };
        for _ in 0..count as usize {
            if scored[k].1 > 0.5 { calibrated_same.push(log10_lr) } else { calibrated_different.push(log10_lr) }
            k += 1;
        }
    }
    cllr(&calibrated_same, &calibrated_different)
}

/// The figures of a study.
#[derive(Clone, Debug, PartialEq)]
pub struct Figures {
    /// Stocks, library sheets, held-out sheets, spots measured.
    pub counts: (usize, usize, usize, usize),
    /// Same-stock and different-stock pairs.
    pub pairs: (usize, usize),
    /// Cllr, bits.
    pub cllr: f64,
    /// Cllr after PAV, bits.
    pub cllr_min: f64,
    /// Same-stock pairs with LR < 1, and with log10 LR < −2.
    pub same_misleading: (usize, usize),
    /// Different-stock pairs with LR > 1, and pairs of different classes with log10 LR > 2.
    pub different_misleading: (usize, usize),
    /// Different-stock pairs with LR > 1 by pair of classes: (class a, class b, misleading, pairs).
    pub by_classes: Vec<(Class, Class, usize, usize)>,
    /// Held-out sheets whose stock ranked first in a search, and trials.
    pub search: (usize, usize),
    /// Median log10 LR of same-stock and of different-stock pairs.
    pub medians: (f64, f64),
}

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// The figures of `pairs`.
pub fn figures(stocks: &[Stock], sheets: &[MeasuredSheet], pairs: &[Pair], search: (usize, usize)) -> Figures {
    let same: Vec<f64> = pairs.iter().filter(|p| p.stock_a == p.stock_b).map(|p| p.log10_lr).collect();
    let different: Vec<&Pair> = pairs.iter().filter(|p| p.stock_a != p.stock_b).collect();
    let different_lr: Vec<f64> = different.iter().map(|p| p.log10_lr).collect();
    let mut by_classes: Vec<(Class, Class, usize, usize)> = Vec::new();
    for p in &different {
        let (mut a, mut b) = (stocks[p.stock_a].class, stocks[p.stock_b].class);
        if a.name() > b.name() {
            std::mem::swap(&mut a, &mut b);
        }
        let misleading = usize::from(p.log10_lr > 0.0);
        match by_classes.iter_mut().find(|(x, y, _, _)| *x == a && *y == b) {
            Some(row) => {
                row.2 += misleading;
                row.3 += 1;
            }
            None => by_classes.push((a, b, misleading, 1)),
        }
    }
    by_classes.sort_by(|x, y| (x.0.name(), x.1.name()).cmp(&(y.0.name(), y.1.name())));
    Figures {
        counts: (stocks.len(), sheets.iter().filter(|s| s.in_library).count(), sheets.iter().filter(|s| !s.in_library).count(), sheets.iter().map(|s| s.measured.spots.len()).sum()),
        pairs: (same.len(), different.len()),
        cllr: cllr(&same, &different_lr),
        cllr_min: cllr_min(&same, &different_lr),
        same_misleading: (same.iter().filter(|&&x| x < 0.0).count(), same.iter().filter(|&&x| x < -2.0).count()),
        different_misleading: (
            different.iter().filter(|p| p.log10_lr > 0.0).count(),
            different.iter().filter(|p| p.log10_lr > 2.0 && stocks[p.stock_a].class != stocks[p.stock_b].class).count(),
        ),
        by_classes,
        search,
        medians: (median(same), median(different_lr)),
    }
}

/// The claims of issue 13, checked: each with whether it held.
pub fn claims(f: &Figures) -> Vec<(String, bool)> {
    let (same_n, diff_n) = f.pairs;
    let rate = f.same_misleading.0 as f64 / same_n.max(1) as f64;
    let search_rate = f.search.0 as f64 / f.search.1.max(1) as f64;
    vec![
        (format!("Cllr {:.3} bits < 0.3 (Cllr_min {:.3})", f.cllr, f.cllr_min), f.cllr < 0.3),
        (format!("same-stock pairs with LR < 1: {} of {same_n} ({:.2} %) ≤ 2 %", f.same_misleading.0, 100.0 * rate), rate <= 0.02),
        (format!("same-stock pairs with log10 LR < −2: {}", f.same_misleading.1), f.same_misleading.1 == 0),
        (format!("different-stock pairs of different classes with log10 LR > 2: {} (of {diff_n} different-stock pairs)", f.different_misleading.1), f.different_misleading.1 == 0),
        (format!("a held-out sheet's stock ranks first in a library search: {} of {} ({:.1} %) ≥ 95 %", f.search.0, f.search.1, 100.0 * search_rate), search_rate >= 0.95),
    ]
}

/// `summary.md`.
pub fn summary_markdown(f: &Figures) -> String {
    let mut s = String::new();
    let (stocks, library, held, spots) = f.counts;
    let _ = writeln!(s, "# Forensic validation: {stocks} stocks, {library} library sheets, {held} held-out sheets, {spots} spots\n");
    let _ = writeln!(s, "| measure | value |\n|---|---|");
    let _ = writeln!(s, "| same-stock pairs | {} |", f.pairs.0);
    let _ = writeln!(s, "| different-stock pairs | {} |", f.pairs.1);
    let _ = writeln!(s, "| Cllr (bits) | {:.3} |", f.cllr);
    let _ = writeln!(s, "| Cllr_min (bits, after PAV) | {:.3} |", f.cllr_min);
    let _ = writeln!(s, "| median log10 LR, same stock | {:+.2} |", f.medians.0);
    let _ = writeln!(s, "| median log10 LR, different stocks | {:+.2} |", f.medians.1);
    let _ = writeln!(s, "| same-stock pairs with LR < 1 (misleading) | {} ({:.2} %) |", f.same_misleading.0, 100.0 * f.same_misleading.0 as f64 / f.pairs.0.max(1) as f64);
    let _ = writeln!(s, "| same-stock pairs with log10 LR < −2 | {} |", f.same_misleading.1);
    let _ = writeln!(s, "| different-stock pairs with LR > 1 (misleading) | {} ({:.2} %) |", f.different_misleading.0, 100.0 * f.different_misleading.0 as f64 / f.pairs.1.max(1) as f64);
    let _ = writeln!(s, "| different-class pairs with log10 LR > 2 | {} |", f.different_misleading.1);
    let _ = writeln!(s, "| library search: own stock ranked first | {} of {} |", f.search.0, f.search.1);
    let _ = writeln!(s, "\n## Misleading evidence for different stocks, by pair of classes\n");
    let _ = writeln!(s, "| classes | pairs | LR > 1 | rate |\n|---|---:|---:|---:|");
    for (a, b, misleading, n) in &f.by_classes {
        let _ = writeln!(s, "| {} – {} | {n} | {misleading} | {:.2} % |", a.name(), b.name(), 100.0 * *misleading as f64 / (*n).max(1) as f64);
    }
    let _ = writeln!(s, "\n## Claims\n");
    for (claim, held) in claims(f) {
        let _ = writeln!(s, "- {} {claim}", if held { "✓" } else { "✗" });
    }
    s
}

/// A Tippett plot: for each log10 LR x, the share of same-stock and of different-stock
/// pairs whose log10 LR exceeds x.
pub fn tippett_svg(pairs: &[Pair], path: &std::path::Path) -> Result<(), String> {
    let same: Vec<f64> = pairs.iter().filter(|p| p.stock_a == p.stock_b).map(|p| p.log10_lr).collect();
    let different: Vec<f64> = pairs.iter().filter(|p| p.stock_a != p.stock_b).map(|p| p.log10_lr).collect();
    let (lo, hi) = (-10.0f64, 6.0f64);
    let curve = |values: &[f64]| -> Vec<(f64, f64)> {
        let n = values.len().max(1) as f64;
        (0..=320).map(|k| lo + (hi - lo) * k as f64 / 320.0).map(|x| (x, values.iter().filter(|&&v| v > x).count() as f64 / n)).collect()
    };
    let root = SVGBackend::new(path, (720, 460)).into_drawing_area();
    let draw = || -> Result<(), Box<dyn std::error::Error>> {
        root.fill(&WHITE)?;
        let mut chart = ChartBuilder::on(&root)
            .caption("Tippett plot: held-out pairs", ("sans-serif", 20))
            .margin(15)
            .x_label_area_size(45)
            .y_label_area_size(60)
            .build_cartesian_2d(lo..hi, 0.0..1.0)?;
        chart
            .configure_mesh()
            .x_desc("log10 LR (same stock : different stocks), x")
            .y_desc("share of pairs with log10 LR > x")
            .draw()?;
        chart.draw_series(LineSeries::new(curve(&same), BLUE.stroke_width(2)))?.label(format!("same stock ({} pairs)", same.len())).legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLUE.stroke_width(2)));
        chart.draw_series(LineSeries::new(curve(&different), RED.stroke_width(2)))?.label(format!("different stocks ({} pairs)", different.len())).legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], RED.stroke_width(2)));
        chart.draw_series(LineSeries::new(vec![(0.0, 0.0), (0.0, 1.0)], BLACK.mix(0.4)))?;
        chart.configure_series_labels().border_style(BLACK).background_style(WHITE.mix(0.9)).position(SeriesLabelPosition::MiddleLeft).draw()?;
        root.present()?;
        Ok(())
    };
    draw().map_err(|e| format!("cannot draw {}: {e}", path.display()))
}
