//! The forensic validation: simulated populations of paper stocks, sheets of each measured
//! as `gonio measure --spots N` measures a sheet on the realistic instrument, a library
//! built from some sheets of every stock, and the likelihood ratios of held-out pairs
//! judged as a forensic LR system is: by Cllr (and its minimum after calibration), the
//! rates of misleading evidence and a Tippett plot (the practice of the Netherlands
//! Forensic Institute's `lir` and the ENFSI guideline).
//!
//! Stocks: the eight reference papers of Table 6 and, about each, more stocks of its kind
//! with σ, ρs and ρd drawn log-normally with [`STOCK_SPREAD_RELATIVE_SD`]
//! (η kept). One draw of the stocks is one population; the study is a campaign over
//! [`Design::draws`] independent draws (each its own seed, [`draw_seed`]), so that no one
//! lucky or unlucky draw decides a claim. A sheet is one multi-spot session
//! ([`super::simulated_sheet`]: one connection, the first spot's calibration for all, a
//! flagged spot replaced) with `--physics real` and `--sheet-variation`
//! [`SPOT_VARIATION_PCT`], each sheet its own seed; the evidence weighs its accepted spots.
//! The same sheets measured with other numbers of spots ([`SPOTS_STUDY`], the same seeds)
//! tell what a spot more buys, for the default of `gonio measure --spots`.

use crate::analysis::classify::{Class, REFERENCES};
use crate::analysis::evidence::{self, LibrarySheet, Questioned, Sheet};
use crate::instrument::sim::{Physics, SimOptions};
use crate::session::{Policy, PolicyChoice};
use plotters::prelude::*;
use rand::SeedableRng;
use rand_chacha::ChaCha12Rng;
use rand_distr::{Distribution, StandardNormal};
use std::fmt::Write as _;

/// How far the stocks drawn about a reference paper lie from it (relative standard
/// deviation of σ, ρs, ρd): the study's own figure, which the evidence is not told (its
/// population is estimated from the study's library).
pub(crate) const STOCK_SPREAD_RELATIVE_SD: [f64; 3] = [0.10, 0.10, 0.10];

/// Between-spot variation of every simulated sheet, percent (`--sheet-variation`).
pub const SPOT_VARIATION_PCT: f64 = 3.0;

/// The seed of the first draw of the stocks; draw `r` is seeded [`FIRST_DRAW_SEED`] + r.
pub(crate) const FIRST_DRAW_SEED: u64 = 0xf0_2e_75_1c;

/// The numbers of spots per sheet the full study compares (`gonio forensic --spots-study`).
pub const SPOTS_STUDY: [usize; 5] = [1, 2, 3, 4, 5];

/// Distances (in between-stock standard deviations, over σ, ρs and ρd together) below
/// which two stocks of a draw are counted as close: 0.5, near twins whose means differ by
/// about 3 % in each parameter or less (as much as two spots of one sheet do), and 1.
pub(crate) const CLOSE: [f64; 2] = [0.5, 1.0];

/// How the simulated world differs from the model's defaults: the figures the truth is
/// drawn with, which the evidence is never told (it estimates its population from the
/// study's library).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Scenario {
    /// Its name (`gonio forensic --scenario`).
    pub name: &'static str,
    /// What it tests, for the summary.
    pub about: &'static str,
    /// Spot-to-spot variation within a sheet, percent (the simulator's `--sheet-variation`).
    pub(crate) spot_pct: f64,
    /// Sheet-to-sheet (lot) variation about the stock, relative standard deviation.
    pub(crate) sheet_relative_sd: f64,
    /// Stocks' spread about each reference paper, relative standard deviation.
    pub(crate) between_relative_sd: f64,
    /// Each drawn stock has a near twin this far from it (relative, in every parameter).
    pub(crate) twin_relative: Option<f64>,
    /// Stock offsets drawn from Student's t with these degrees of freedom (heavy tails)
    /// instead of the normal.
    pub(crate) tail_dof: Option<f64>,
    /// Correlation of the three parameters' stock offsets.
    pub correlation: f64,
    /// Held-out sheets of odd number are measured on a second instrument whose white tile
    /// is off by N(0, this %) per sheet (the first instrument: the realistic 0.5 %).
    pub(crate) second_instrument_tile_pct: Option<f64>,
    /// The fit tests the model's extensions (`--model extended`, the default), for every
    /// sheet of the library and the pairs alike; else it fits the paper's model alone,
    /// as the worlds measured before the extensions did.
    pub(crate) extensions: bool,
    /// Every stock departs from the paper's TSL surface by a shape drawn for it from the
    /// shapes campaign's (`gonio accuracy --shapes`: a haze, heavier or lighter tails, an
    /// off-specular peak, an Oren–Nayar body, …, mild or strong, or none), its sheets
    /// alike.
    pub(crate) shapes: bool,
}

impl Scenario {
    /// The world the study drew before the three-level model: 3 % between spots, 10 %
    /// between stocks, nothing between sheets.
    pub(crate) const AS_TODAY: Scenario = Scenario {
        name: "as-today",
        about: "3 % between spots, no sheet level, stocks 10 % about each paper",
        spot_pct: 3.0,
        sheet_relative_sd: 0.0,
        between_relative_sd: 0.10,
        twin_relative: None,
        tail_dof: None,
        correlation: 0.0,
        second_instrument_tile_pct: None,
        extensions: false,
        shapes: false,
    };

    /// Every scenario of the validation campaign (docs/FORENSIC.md).
    pub const ALL: [Scenario; 11] = [
        Scenario::AS_TODAY,
        Scenario {
            name: "spots-1pct",
            about: "1 % between spots",
            spot_pct: 1.0,
            ..Scenario::AS_TODAY
        },
        Scenario {
            name: "spots-6pct",
            about: "6 % between spots",
            spot_pct: 6.0,
            ..Scenario::AS_TODAY
        },
        Scenario {
            name: "stocks-5pct",
            about: "stocks 5 % about each paper",
            between_relative_sd: 0.05,
            ..Scenario::AS_TODAY
        },
        Scenario {
            name: "stocks-20pct",
            about: "stocks 20 % about each paper",
            between_relative_sd: 0.20,
            ..Scenario::AS_TODAY
        },
        Scenario {
            name: "near-twins",
            about: "every drawn stock has a twin 1.5 % away",
            twin_relative: Some(0.015),
            ..Scenario::AS_TODAY
        },
        Scenario {
            name: "sheets-3pct",
            about: "sheets (lots) 3 % about their stock, spots 3 % about their sheet",
            sheet_relative_sd: 0.03,
            ..Scenario::AS_TODAY
        },
        Scenario {
            name: "heavy-tailed",
            about: "stock offsets from Student's t (3 dof), the parameters correlated 0.6",
            tail_dof: Some(3.0),
            correlation: 0.6,
            ..Scenario::AS_TODAY
        },
        Scenario {
            name: "second-instrument",
            about: "half the held-out sheets on a second instrument, its tile off by N(0, 1.5 %) per sheet",
            second_instrument_tile_pct: Some(1.5),
            ..Scenario::AS_TODAY
        },
        Scenario {
            name: "extensions",
            about: "as-today, the fit testing the model's extensions",
            extensions: true,
            ..Scenario::AS_TODAY
        },
        Scenario {
            name: "shapes",
            about: "every stock a shape of the shapes campaign (or none), drawn for it; the fit testing the model's extensions",
            extensions: true,
            shapes: true,
            ..Scenario::AS_TODAY
        },
    ];

    /// The scenario called `name`.
    pub fn named(name: &str) -> Option<Scenario> {
        Scenario::ALL.into_iter().find(|s| s.name == name)
    }
}

/// The size of a study.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Design {
    /// The world drawn.
    pub scenario: Scenario,
    /// Independent draws of the population (each: the reference papers and stocks drawn
    /// about each).
    pub draws: usize,
    /// The number of the first draw (its seed [`draw_seed`]): a study of draws not used
    /// before confirms one whose figures chose something (the number of spots).
    pub first_draw: usize,
    /// Stocks drawn about each reference paper besides the paper itself.
    pub drawn_per_paper: usize,
    /// Sheets of each stock in the library.
    pub library_sheets: usize,
    /// Sheets of each stock held out for the pairs.
    pub held_out_sheets: usize,
    /// Clean spots planned per sheet (`gonio measure --spots`) for the claims.
    pub spots: usize,
    /// How each spot is measured (`gonio measure --policy`).
    pub policy: PolicyChoice,
}

impl Design {
    /// The study of docs/FORENSIC.md: 10 draws of 32 stocks, 2 library and 4 held-out
    /// sheets of 3 spots.
    pub const FULL: Design = Design {
        scenario: Scenario::AS_TODAY,
        draws: 10,
        first_draw: 0,
        drawn_per_paper: 3,
        library_sheets: 2,
        held_out_sheets: 4,
        spots: crate::analysis::spots::DEFAULT_SPOTS as usize,
        policy: PolicyChoice::Adaptive,
    };
    /// A small one for the tests: 2 draws of 24 stocks, 2 library and 2 held-out sheets
    /// of 2 spots.
    pub const SMALL: Design = Design {
        scenario: Scenario::AS_TODAY,
        draws: 2,
        first_draw: 0,
        drawn_per_paper: 2,
        library_sheets: 2,
        held_out_sheets: 2,
        spots: 2,
        policy: PolicyChoice::Adaptive,
    };

    /// Sheets of every stock.
    pub(crate) fn sheets_per_stock(&self) -> usize {
        self.library_sheets + self.held_out_sheets
    }
}

/// A simulated stock.
#[derive(Clone, Debug, PartialEq)]
pub struct Stock {
    /// Its name (`G`, `G#1`, …), unique within its draw.
    pub name: String,
    /// The simulator's sample (`custom:σ,ρs,ρd,η`).
    pub sample: String,
    /// Its true σ (degrees), ρs, ρd.
    pub params: [f64; 3],
    /// The class of the reference paper it was drawn about.
    pub class: Class,
    /// Its shape: the paper's TSL surface, or a departure from it (the scenario's
    /// `shapes`).
    pub shape: super::shapes::Shape,
}

/// The seed of draw `draw` of the population.
pub fn draw_seed(draw: usize) -> u64 {
    FIRST_DRAW_SEED + draw as u64
}

/// The stocks of draw `draw`: each reference paper and `drawn_per_paper` drawn about it
/// (and each drawn one's twin, when the scenario has twins).
pub fn stocks(design: &Design, draw: usize) -> Vec<Stock> {
    let scenario = &design.scenario;
    let mut rng = ChaCha12Rng::seed_from_u64(draw_seed(draw));
    // Shapes from a stream of their own: the stocks' parameters are those of the same draw
    // without them.
    let mut shape_rng = ChaCha12Rng::seed_from_u64(draw_seed(draw) ^ SHAPES_STREAM);
    let mut out = Vec::new();
    for r in &REFERENCES {
        let p = r.params;
        let paper = [p.sigma_deg, p.rho_s, p.rho_d];
        let mut push = |name: String, params: [f64; 3]| {
            let shape = if scenario.shapes {
                stock_shape(&mut shape_rng, params[0])
            } else {
                super::shapes::Shape::Tsl
            };
            out.push(Stock {
                name,
                sample: format!("custom:{},{},{},{}", params[0], params[1], params[2], p.eta),
                params,
                class: r.class,
                shape,
            })
        };
        push(r.name.to_string(), paper);
        for k in 1..=design.drawn_per_paper {
            let z = correlated_offsets(&mut rng, scenario);
            let params: [f64; 3] = std::array::from_fn(|i| {
                let s2 = (1.0 + scenario.between_relative_sd.powi(2)).ln();
                paper[i] * (s2.sqrt() * z[i] - 0.5 * s2).exp()
            });
            push(format!("{}#{k}", r.name), params);
            if let Some(twin) = scenario.twin_relative {
                // The twin: every parameter `twin` away, in a drawn direction.
                let signs: [f64; 3] = std::array::from_fn(|_| {
                    let u: f64 = StandardNormal.sample(&mut rng);
                    u.signum()
                });
                push(
                    format!("{}#{k}t", r.name),
                    std::array::from_fn(|i| params[i] * (1.0 + twin * signs[i])),
                );
            }
        }
    }
    out
}

/// The stream the stocks' shapes are drawn from (XORed into the draw's seed).
const SHAPES_STREAM: u64 = 0x5a4e_5e5e;

/// σ above which a stock is not given a Beckmann lobe: the simulator refuses one beyond
/// about 39° (it has no peak at specular there), and a sheet's spots vary about the stock.
const BECKMANN_MAX_SIGMA_DEG: f64 = 30.0;

/// A shape for a stock of σ `sigma_deg`: every shape of the shapes campaign (the paper's
/// surface among them) as likely, but a Beckmann lobe where σ is too wide for one.
fn stock_shape(rng: &mut ChaCha12Rng, sigma_deg: f64) -> super::shapes::Shape {
    use super::shapes::{KINDS, Kind, Shape};
    use rand::Rng;
    let shapes: Vec<Shape> = Shape::all(&KINDS)
        .into_iter()
        .filter(|s| {
            sigma_deg < BECKMANN_MAX_SIGMA_DEG
                || !matches!(
                    s,
                    Shape::Departure(Kind::Lobe(crate::instrument::sim::LobeChoice::Beckmann), _)
                )
        })
        .collect();
    shapes[rng.random_range(0..shapes.len())]
}

/// Three standard offsets with the scenario's correlation, from the normal or (heavy
/// tails) Student's t scaled to unit variance.
fn correlated_offsets(rng: &mut ChaCha12Rng, scenario: &Scenario) -> [f64; 3] {
    let z: [f64; 3] = std::array::from_fn(|_| StandardNormal.sample(rng));
    // One common factor: corr(z_i, z_j) = ρ.
    let common: f64 = StandardNormal.sample(rng);
    let rho = scenario.correlation.clamp(0.0, 0.99);
    let mixed = z.map(|zi| rho.sqrt() * common + (1.0 - rho).sqrt() * zi);
    match scenario.tail_dof {
        Some(nu) if nu > 2.0 => {
            // t = z / √(χ²ν/ν), scaled by √((ν−2)/ν) to unit variance.
            let chi2: f64 = (0..nu.round() as usize)
                .map(|_| {
                    let g: f64 = StandardNormal.sample(rng);
                    g * g
                })
                .sum();
            let scale = ((nu - 2.0) / nu).sqrt() / (chi2 / nu).sqrt();
            mixed.map(|m| m * scale)
        }
        _ => mixed,
    }
}

/// How far apart two stocks' true means are, in between-stock standard deviations
/// ([`STOCK_SPREAD_RELATIVE_SD`], in log space) over σ, ρs and ρd together:
/// two stocks drawn about one paper are 2.3 apart on average, a drawn stock and its paper 1.6.
pub fn distance(a: &Stock, b: &Stock) -> f64 {
    let sd = STOCK_SPREAD_RELATIVE_SD;
    (0..3)
        .map(|i| ((a.params[i] / b.params[i]).ln() / (1.0 + sd[i] * sd[i]).ln().sqrt()).powi(2))
        .sum::<f64>()
        .sqrt()
}

/// One sheet to measure.
#[derive(Clone, Debug, PartialEq)]
pub struct SheetSpec {
    /// The draw of the population.
    pub draw: usize,
    /// Index into the draw's stocks.
    pub stock: usize,
    /// Sheet number within the stock (library sheets first).
    pub sheet: usize,
    /// Clean spots planned (`gonio measure --spots`).
    pub spots: usize,
    /// The simulator's seed: the sheet's own (its spots, its instrument draw), the same
    /// whatever its number of spots, so that the spots study compares like with like.
    pub seed: u64,
}

/// The seed of a sheet.
pub fn sheet_seed(draw: usize, stock: usize, sheet: usize) -> u64 {
    1 + ((draw as u64 * 10_000 + stock as u64) * 1_000 + sheet as u64)
}

/// Every sheet of the study, measured with each number of spots of `spot_counts` (and the
/// design's own).
pub fn plan(design: &Design, spot_counts: &[usize]) -> Vec<SheetSpec> {
    let counts = spot_counts_of(design, spot_counts);
    let n_stocks = stocks_per_draw(design);
    let mut out = Vec::new();
    for draw in 0..design.draws {
        for stock in 0..n_stocks {
            for sheet in 0..design.sheets_per_stock() {
                for &spots in &counts {
                    out.push(SheetSpec {
                        draw,
                        stock,
                        sheet,
                        spots,
                        seed: sheet_seed(design.first_draw + draw, stock, sheet),
                    });
                }
            }
        }
    }
    out
}

/// Stocks in each draw: the papers, the stocks drawn about them and their twins.
pub(crate) fn stocks_per_draw(design: &Design) -> usize {
    let twins = usize::from(design.scenario.twin_relative.is_some());
    REFERENCES.len() * (1 + design.drawn_per_paper * (1 + twins))
}

/// `spot_counts` with the design's own, sorted, without repeats.
pub fn spot_counts_of(design: &Design, spot_counts: &[usize]) -> Vec<usize> {
    let mut counts: Vec<usize> = spot_counts.iter().copied().chain([design.spots]).collect();
    counts.sort_unstable();
    counts.dedup();
    counts
}

/// A measured sheet of the study.
#[derive(Clone, Debug, PartialEq)]
pub struct MeasuredSheet {
    /// The draw of the population.
    pub draw: usize,
    /// Index into the draw's stocks.
    pub stock: usize,
    /// Sheet number within the stock.
    pub sheet: usize,
    /// Whether it belongs to the library (else held out).
    pub in_library: bool,
    /// Clean spots planned.
    pub planned: usize,
    /// Spots measured, replacements of flagged spots included.
    pub(crate) measured_spots: usize,
    /// Spots excluded (flagged while the sheet had a clean one).
    pub excluded: usize,
    /// No spot came out clean: every spot was kept, with its flags.
    pub(crate) no_clean_spot: bool,
    /// Device time of the sheet: every spot's measuring time and the first spot's setup
    /// (homing, dark, white), seconds.
    pub device_seconds: f64,
    /// The sheet as the evidence weighs it: its accepted spots.
    pub measured: Sheet,
    /// The instrument that measured it (`first`, or `second` in the second-instrument
    /// scenario).
    pub instrument: &'static str,
}

/// Why a sheet of the study could not be measured.
#[derive(Debug, thiserror::Error)]
pub enum SheetError {
    /// More spots than a sheet's session numbers.
    #[error("{0} spots per sheet")]
    TooManySpots(usize),
    /// The simulated sheet failed.
    #[error("{0}")]
    Simulation(super::SimulationError),
}

/// Why the study could not be measured or drawn.
#[derive(Debug, thiserror::Error)]
pub enum ForensicError {
    /// A worker thread panicked, leaving its sheet without a result.
    #[error("a worker panicked")]
    Panicked,
    /// A sheet could not be measured.
    #[error("draw {draw} {stock} sheet {sheet} ({spots} spots): {error}")]
    Sheet {
        /// The population draw.
        draw: usize,
        /// The stock's name.
        stock: String,
        /// The sheet of the stock.
        sheet: usize,
        /// Spots planned.
        spots: usize,
        /// Why.
        error: Box<SheetError>,
    },
    /// The Tippett plot could not be drawn.
    #[error("cannot draw {}: {message}", .path.display())]
    Draw {
        /// The SVG file.
        path: std::path::PathBuf,
        /// The plotting library's message.
        message: String,
    },
}

/// Measure one sheet: one multi-spot session, as `gonio measure --sim --spots N`.
pub fn measure(
    stocks: &[Stock],
    spec: &SheetSpec,
    design: &Design,
) -> Result<MeasuredSheet, SheetError> {
    let stock = &stocks[spec.stock];
    let scenario = &design.scenario;
    // The sheet's own parameters: its stock's, moved by the sheet (lot) level.
    let mut rng = ChaCha12Rng::seed_from_u64(spec.seed ^ 0x5ee7_1e7e);
    let s2 = (1.0 + scenario.sheet_relative_sd.powi(2)).ln();
    let params: [f64; 3] = std::array::from_fn(|i| {
        let z: f64 = StandardNormal.sample(&mut rng);
        stock.params[i] * (s2.sqrt() * z - 0.5 * s2).exp()
    });
    let eta = stock
        .sample
        .rsplit(',')
        .next()
        .and_then(|e| e.parse::<f64>().ok())
        .unwrap_or(2.0);
    let sample = format!("custom:{},{},{},{eta}", params[0], params[1], params[2]);
    let held_out = spec.sheet >= design.library_sheets;
    let second = held_out && spec.sheet % 2 == 1 && scenario.second_instrument_tile_pct.is_some();
    let (lobe, lobe_weight, departure) = stock.shape.sheet_options(params[0]);
    let options = SimOptions {
        seed: spec.seed,
        physics: Physics::Real,
        lobe,
        lobe_weight,
        departure: departure.into_iter().collect(),
        sheet_variation: scenario.spot_pct,
        tile_error: if second {
            scenario.second_instrument_tile_pct
        } else {
            None
        },
        ..SimOptions::default()
    };
    let run = super::SimulatedRun {
        sample: if scenario.sheet_relative_sd > 0.0 {
            &sample
        } else {
            &stock.sample
        },
        options: &options,
        policy: Policy::from(design.policy),
        integration_ms: None,
    };
    let planned = u16::try_from(spec.spots).map_err(|_| SheetError::TooManySpots(spec.spots))?;
    let (outcomes, summary, results) = super::simulated_sheet(&run, planned, |session| {
        // Each world fits the model it names, whatever the process's default: its
        // figures in docs/FORENSIC.md are of that model.
        session.with_model_extensions(scenario.extensions)
    })
    .map_err(SheetError::Simulation)?;
    let device_seconds = outcomes.iter().map(|o| o.device_seconds).sum::<f64>()
        + outcomes.first().map_or(0.0, |o| o.setup_seconds);
    Ok(MeasuredSheet {
        draw: spec.draw,
        stock: spec.stock,
        sheet: spec.sheet,
        in_library: spec.sheet < design.library_sheets,
        planned: spec.spots,
        measured_spots: results.len(),
        excluded: results.len() - summary.accepted,
        no_clean_spot: !results.is_empty()
            && !results.iter().any(|r| crate::analysis::flags::ok(&r.flags)),
        device_seconds,
        measured: summary.sheet(&results),
        instrument: if second { "second" } else { "first" },
    })
}

/// A measured study: its design, every draw's stocks and every sheet.
#[derive(Clone, Debug, PartialEq)]
pub struct Campaign {
    /// The design.
    pub design: Design,
    /// The stocks of each draw.
    pub stocks: Vec<Vec<Stock>>,
    /// Every sheet, with every number of spots measured.
    pub sheets: Vec<MeasuredSheet>,
}

/// Measure the whole study (every sheet with each number of spots of `spot_counts` and the
/// design's own) on `threads` threads; `progress` after each sheet.
pub fn measure_all(
    design: &Design,
    spot_counts: &[usize],
    threads: usize,
    progress: &(dyn Fn() + Sync),
) -> Result<Campaign, ForensicError> {
    let stocks: Vec<Vec<Stock>> = (0..design.draws)
        .map(|draw| self::stocks(design, design.first_draw + draw))
        .collect();
    let specs = plan(design, spot_counts);
    let measured = super::parallel(&specs, threads, progress, |spec| {
        measure(&stocks[spec.draw], spec, design)
    });
    if measured.len() != specs.len() {
        return Err(ForensicError::Panicked);
    }
    let sheets = specs
        .iter()
        .zip(measured)
        .map(|(spec, sheet)| {
            sheet.map_err(|error| ForensicError::Sheet {
                draw: spec.draw,
                stock: stocks[spec.draw][spec.stock].name.clone(),
                sheet: spec.sheet,
                spots: spec.spots,
                error: Box::new(error),
            })
        })
        .collect::<Result<Vec<_>, _>>()?;
    Ok(Campaign {
        design: *design,
        stocks,
        sheets,
    })
}

/// One held-out pair and its evidence.
#[derive(Clone, Debug, PartialEq)]
pub struct Pair {
    /// The draw of the population.
    pub draw: usize,
    /// Stock of the first sheet.
    pub stock_a: usize,
    /// Stock of the second.
    pub stock_b: usize,
    /// The reported log10 LR (calibrated, within the library's bounds).
    pub log10_lr: f64,
    /// The model's own.
    pub raw_log10_lr: f64,
    /// The library's bounds it was held within.
    pub bounds: (f64, f64),
    /// The kinds of the warnings it carried.
    pub warnings: Vec<&'static str>,
    /// Whether its sheets were measured on different instruments.
    pub(crate) instruments_differ: bool,
}

/// One draw's evidence: every held-out pair and the library searches.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct DrawEvidence {
    /// Every pair of held-out sheets.
    pub pairs: Vec<Pair>,
    /// Held-out sheets whose own stock ranked first, and sheets searched.
    pub search: (usize, usize),
    /// Each search that missed: the sheet's stock and the stock ranked first.
    pub misses: Vec<(usize, usize)>,
}

/// The library of `sheets` labelled by stock name.
fn library(stocks: &[Stock], sheets: &[&MeasuredSheet]) -> Vec<LibrarySheet> {
    sheets
        .iter()
        .filter(|s| s.in_library)
        .map(|s| LibrarySheet {
            stock: stocks[s.stock].name.clone(),
            lot: None,
            instrument: Some(s.instrument.to_string()),
            sheet: s.measured.clone(),
        })
        .collect()
}

/// One draw's evidence from its sheets (of one number of spots): the library's population,
/// every held-out pair's log10 LR, and each held-out sheet searched against the library's
/// stocks (each stock's library sheets pooled) as `gonio library search` ranks them.
pub(crate) fn draw_evidence(
    draw: usize,
    stocks: &[Stock],
    sheets: &[&MeasuredSheet],
) -> Result<DrawEvidence, evidence::EvidenceError> {
    let library = library(stocks, sheets);
    let population = evidence::validation::validate(&library)?;
    let bounds = population
        .validation
        .as_ref()
        .map_or((0.0, 0.0), |v| v.bounds);
    let held: Vec<&&MeasuredSheet> = sheets.iter().filter(|s| !s.in_library).collect();
    let questioned = |s: &MeasuredSheet| Questioned {
        sheet: s.measured.clone(),
        instrument: Some(s.instrument.to_string()),
        ..Questioned::default()
    };
    let mut pairs = Vec::new();
    for (i, a) in held.iter().enumerate() {
        for b in &held[i + 1..] {
            let e = evidence::weigh(&questioned(a), &questioned(b), &population);
            pairs.push(Pair {
                draw,
                stock_a: a.stock,
                stock_b: b.stock,
                log10_lr: e.ratio.log10_lr,
                raw_log10_lr: e.ratio.raw_log10_lr,
                bounds,
                warnings: e.warnings.iter().map(evidence::Warning::kind).collect(),
                instruments_differ: a.instrument != b.instrument,
            });
        }
    }
    let mut misses = Vec::new();
    for s in &held {
        let first = evidence::search(&Questioned::of(s.measured.clone()), &population)
            .ranking
            .into_iter()
            .next();
        let first = first.and_then(|r| stocks.iter().position(|k| k.name == r.stock));
        if first != Some(s.stock) {
            misses.push((s.stock, first.unwrap_or(usize::MAX)));
        }
    }
    Ok(DrawEvidence {
        pairs,
        search: (held.len() - misses.len(), held.len()),
        misses,
    })
}

/// Cllr and Cllr_min are the evidence module's: the study measures with the validation's
/// own yardstick.
pub use crate::analysis::evidence::validation::{cllr, cllr_min};

/// The 95 % Wilson score interval of a rate of `k` in `n` (for n = 0, [0, 1]).
pub fn wilson(k: usize, n: usize) -> (f64, f64) {
    if n == 0 {
        return (0.0, 1.0);
    }
    let z = 1.959_963_984_540_054_f64;
    let (n, p) = (n as f64, k as f64 / n as f64);
    let denominator = 1.0 + z * z / n;
    let centre = (p + z * z / (2.0 * n)) / denominator;
    let half = z * (p * (1.0 - p) / n + z * z / (4.0 * n * n)).sqrt() / denominator;
    ((centre - half).max(0.0), (centre + half).min(1.0))
}

/// How the planned spots went: measured, replaced, excluded.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SpotUse {
    /// Sheets measured.
    pub sheets: usize,
    /// Spots measured, replacements included.
    pub measured: usize,
    /// Spots measured in place of flagged ones (beyond the planned).
    pub replaced: usize,
    /// Spots excluded from their sheet (flagged while the sheet had a clean one).
    pub excluded: usize,
    /// Sheets with no clean spot (every spot kept, with its flags).
    pub(crate) no_clean_spot: usize,
    /// Sheets with fewer accepted spots than planned (the replacements spent).
    pub short: usize,
}

/// The nearest two different stocks of a draw.
#[derive(Clone, Debug, PartialEq)]
pub struct Nearest {
    /// Their names.
    pub stocks: (String, String),
    /// Their distance ([`distance`]).
    pub distance: f64,
    /// Their relative differences in σ, ρs, ρd, percent.
    pub(crate) difference_pct: [f64; 3],
    /// Pairs of the draw's stocks closer than each distance of [`CLOSE`].
    pub(crate) close_pairs: [usize; 2],
}

/// The nearest two different stocks of `stocks`.
pub fn nearest(stocks: &[Stock]) -> Option<Nearest> {
    let mut best: Option<(usize, usize, f64)> = None;
    let mut close_pairs = [0; 2];
    for i in 0..stocks.len() {
        for j in i + 1..stocks.len() {
            let d = distance(&stocks[i], &stocks[j]);
            for (count, limit) in close_pairs.iter_mut().zip(CLOSE) {
                *count += usize::from(d < limit);
            }
            if best.is_none_or(|(_, _, b)| d < b) {
                best = Some((i, j, d));
            }
        }
    }
    best.map(|(i, j, d)| Nearest {
        stocks: (stocks[i].name.clone(), stocks[j].name.clone()),
        distance: d,
        difference_pct: std::array::from_fn(|k| {
            100.0 * (stocks[j].params[k] / stocks[i].params[k] - 1.0)
        }),
        close_pairs,
    })
}

/// One draw's figures.
#[derive(Clone, Debug, PartialEq)]
pub struct DrawRow {
    /// The draw.
    pub draw: usize,
    /// Its seed ([`draw_seed`]).
    pub seed: u64,
    /// Same-stock and different-stock pairs.
    pub pairs: (usize, usize),
    /// Cllr, bits.
    pub cllr: f64,
    /// Cllr after PAV, bits.
    pub cllr_min: f64,
    /// Same-stock pairs with LR < 1.
    pub same_misleading: usize,
    /// Different-stock pairs with LR > 1.
    pub different_misleading: usize,
    /// Held-out sheets whose stock ranked first, and sheets searched.
    pub search: (usize, usize),
    /// The draw's nearest two stocks.
    pub nearest: Option<Nearest>,
    /// The largest distance between a missed sheet's stock and the stock ranked first in
    /// its place (`None` without a miss): how close two stocks must be to be confused.
    pub(crate) farthest_miss: Option<f64>,
}

/// The figures of a study for one number of spots per sheet, pooled over its draws.
#[derive(Clone, Debug, PartialEq)]
pub struct Figures {
    /// Clean spots planned per sheet.
    pub spots: usize,
    /// Draws of the population.
    pub draws: usize,
    /// Stocks per draw, library sheets, held-out sheets (over every draw), spots accepted.
    pub counts: (usize, usize, usize, usize),
    /// How the planned spots went.
    pub spot_use: SpotUse,
    /// Mean device time per sheet, seconds (its spots' and the first spot's setup).
    pub device_seconds_per_sheet: f64,
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
    /// Each draw's figures.
    pub per_draw: Vec<DrawRow>,
    /// The named pairs of reference papers, over every draw: (paper a, paper b,
    /// pairs, pairs with log10 LR < −2, the largest log10 LR).
    pub named: Vec<(&'static str, &'static str, usize, usize, f64)>,
    /// The scenario drawn.
    pub scenario: &'static str,
    /// Pairs reported outside their library's bounds (must be none).
    pub outside_bounds: usize,
    /// The narrowest and widest bounds of the draws' libraries.
    pub bounds_range: ((f64, f64), (f64, f64)),
    /// Cllr of the model's raw ratios, before calibration and bounds.
    pub cllr_raw: f64,
    /// Same-stock pairs reported below 1/100 and different-stock pairs above 100.
    pub strong_misleading: (usize, usize),
    /// The reported decades.
    pub bins: Vec<Decade>,
    /// Pairs on different instruments, and those of them warned so.
    pub instrument_pairs: (usize, usize),
    /// Pairs with a sheet outside the population, and pairs with a scatter warning.
    pub warned: (usize, usize),
}

/// Pairs a decade must hold for its calibration to be judged.
pub(crate) const BIN_MIN_PAIRS: usize = 20;

/// One decade of reported log10 LR in a study.
#[derive(Clone, Debug, PartialEq)]
pub struct Decade {
    /// Its lower edge: log10 LR in [from, from + 1).
    pub from: f64,
    /// Same-stock pairs reported in it.
    pub same: usize,
    /// Different-stock pairs reported in it.
    pub different: usize,
    /// The mean reported log10 LR of its pairs.
    pub reported: f64,
    /// The observed log10 ratio of its shares of same- and of different-stock pairs, half
    /// a pair added to each count.
    pub observed: f64,
    /// That ratio's 95 % interval (from the Wilson intervals of the two shares): with few
    /// same-stock pairs, a decade holding none of them says only that the ratio is below
    /// the upper end.
    pub observed_interval: (f64, f64),
}

impl Decade {
    /// How far the reported value lies outside the observed ratio's interval (0 inside).
    pub fn miss(&self) -> f64 {
        (self.observed_interval.0 - self.reported)
            .max(self.reported - self.observed_interval.1)
            .max(0.0)
    }
}

/// The reported decades of `pairs` (see [`Figures::bins`]).
fn bins(pairs: &[Pair]) -> Vec<Decade> {
    let n_same = pairs.iter().filter(|p| p.stock_a == p.stock_b).count();
    let n_different = pairs.iter().filter(|p| p.stock_a != p.stock_b).count();
    let mut decades: std::collections::BTreeMap<i64, (usize, usize, f64)> = Default::default();
    for p in pairs {
        let e = decades.entry(p.log10_lr.floor() as i64).or_default();
        if p.stock_a == p.stock_b {
            e.0 += 1
        } else {
            e.1 += 1
        }
        e.2 += p.log10_lr;
    }
    let (ns, nd) = (n_same.max(1) as f64, n_different.max(1) as f64);
    decades
        .into_iter()
        .map(|(from, (same, different, sum))| {
            let (s_lo, s_hi) = wilson(same, n_same);
            let (d_lo, d_hi) = wilson(different, n_different);
            Decade {
                from: from as f64,
                same,
                different,
                reported: sum / (same + different) as f64,
                observed: (((same as f64 + 0.5) / ns) / ((different as f64 + 0.5) / nd)).log10(),
                observed_interval: ((s_lo / d_hi).log10(), (s_hi / d_lo).log10()),
            }
        })
        .collect()
}

/// Pairs of reference papers the issue names as to be told apart (LR < 1/100).
pub(crate) const NAMED_PAIRS: [(&str, &str); 2] = [("J3", "J4"), ("PPC", "J3")];

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn split(pairs: &[Pair]) -> (Vec<f64>, Vec<f64>) {
    let same = pairs
        .iter()
        .filter(|p| p.stock_a == p.stock_b)
        .map(|p| p.log10_lr)
        .collect();
    let different = pairs
        .iter()
        .filter(|p| p.stock_a != p.stock_b)
        .map(|p| p.log10_lr)
        .collect();
    (same, different)
}

/// What the targets are checked on, from the pairs of a study.
struct Checks {
    outside_bounds: usize,
    bounds_range: ((f64, f64), (f64, f64)),
    cllr_raw: f64,
    strong_misleading: (usize, usize),
    bins: Vec<Decade>,
    instrument_pairs: (usize, usize),
    warned: (usize, usize),
}

impl Checks {
    fn of(pairs: &[Pair]) -> Checks {
        let width = |b: &(f64, f64)| b.1 - b.0;
        let bounds: Vec<(f64, f64)> = pairs.iter().map(|p| p.bounds).collect();
        let narrowest = bounds
            .iter()
            .copied()
            .min_by(|a, b| width(a).total_cmp(&width(b)))
            .unwrap_or((0.0, 0.0));
        let widest = bounds
            .iter()
            .copied()
            .max_by(|a, b| width(a).total_cmp(&width(b)))
            .unwrap_or((0.0, 0.0));
        let same = |p: &&Pair| p.stock_a == p.stock_b;
        let different = |p: &&Pair| p.stock_a != p.stock_b;
        let raw_same: Vec<f64> = pairs.iter().filter(same).map(|p| p.raw_log10_lr).collect();
        let raw_different: Vec<f64> = pairs
            .iter()
            .filter(different)
            .map(|p| p.raw_log10_lr)
            .collect();
        let warned = |kind: &str| pairs.iter().filter(|p| p.warnings.contains(&kind)).count();
        Checks {
            outside_bounds: pairs
                .iter()
                .filter(|p| p.log10_lr < p.bounds.0 - 1e-12 || p.log10_lr > p.bounds.1 + 1e-12)
                .count(),
            bounds_range: (narrowest, widest),
            cllr_raw: cllr(&raw_same, &raw_different),
            strong_misleading: (
                pairs
                    .iter()
                    .filter(same)
                    .filter(|p| p.log10_lr < -2.0)
                    .count(),
                pairs
                    .iter()
                    .filter(different)
                    .filter(|p| p.log10_lr > 2.0)
                    .count(),
            ),
            bins: bins(pairs),
            instrument_pairs: (
                pairs.iter().filter(|p| p.instruments_differ).count(),
                pairs
                    .iter()
                    .filter(|p| {
                        p.instruments_differ && p.warnings.contains(&"different-instruments")
                    })
                    .count(),
            ),
            warned: (warned("out-of-population"), warned("scatter")),
        }
    }
}

/// The figures of `campaign`'s sheets of `spots` spots, and every held-out pair of every
/// draw; the draws weighed on `threads` threads.
pub fn figures(
    campaign: &Campaign,
    spots: usize,
    threads: usize,
) -> Result<(Figures, Vec<Pair>), evidence::EvidenceError> {
    let sheets: Vec<&MeasuredSheet> = campaign
        .sheets
        .iter()
        .filter(|s| s.planned == spots)
        .collect();
    let draws: Vec<usize> = (0..campaign.stocks.len()).collect();
    let weighed = super::parallel(&draws, threads, &|| {}, |&draw| {
        let of_draw: Vec<&MeasuredSheet> =
            sheets.iter().copied().filter(|s| s.draw == draw).collect();
        draw_evidence(draw, &campaign.stocks[draw], &of_draw)
    });
    assert_eq!(weighed.len(), draws.len(), "a worker panicked");
    let mut pairs: Vec<Pair> = Vec::new();
    let mut per_draw = Vec::new();
    let mut search = (0, 0);
    for ((draw, stocks), e) in campaign.stocks.iter().enumerate().zip(weighed) {
        let e = e?;
        let (same, different) = split(&e.pairs);
        per_draw.push(DrawRow {
            draw: campaign.design.first_draw + draw,
            seed: draw_seed(campaign.design.first_draw + draw),
            pairs: (same.len(), different.len()),
            cllr: cllr(&same, &different),
            cllr_min: cllr_min(&same, &different),
            same_misleading: same.iter().filter(|&&x| x < 0.0).count(),
            different_misleading: different.iter().filter(|&&x| x > 0.0).count(),
            search: e.search,
            nearest: nearest(stocks),
            farthest_miss: e
                .misses
                .iter()
                .filter_map(|&(a, b)| stocks.get(b).map(|b| distance(&stocks[a], b)))
                .max_by(f64::total_cmp),
        });
        search.0 += e.search.0;
        search.1 += e.search.1;
        pairs.extend(e.pairs);
    }
    let class = |p: &Pair, stock: usize| campaign.stocks[p.draw][stock].class;
    let (same, different_lr) = split(&pairs);
    let different: Vec<&Pair> = pairs.iter().filter(|p| p.stock_a != p.stock_b).collect();
    let by_classes = by_classes(campaign, &different);
    let spot_use = spot_use(&sheets);
    let named = named_pairs(campaign, &pairs);
    let checks = Checks::of(&pairs);
    let figures = Figures {
        scenario: campaign.design.scenario.name,
        outside_bounds: checks.outside_bounds,
        bounds_range: checks.bounds_range,
        cllr_raw: checks.cllr_raw,
        strong_misleading: checks.strong_misleading,
        bins: checks.bins,
        instrument_pairs: checks.instrument_pairs,
        warned: checks.warned,
        named,
        spots,
        draws: campaign.stocks.len(),
        counts: (
            campaign.stocks.first().map_or(0, Vec::len),
            sheets.iter().filter(|s| s.in_library).count(),
            sheets.iter().filter(|s| !s.in_library).count(),
            sheets.iter().map(|s| s.measured.spots.len()).sum(),
        ),
        spot_use,
        device_seconds_per_sheet: sheets.iter().map(|s| s.device_seconds).sum::<f64>()
            / sheets.len().max(1) as f64,
        pairs: (same.len(), different.len()),
        cllr: cllr(&same, &different_lr),
        cllr_min: cllr_min(&same, &different_lr),
        same_misleading: (
            same.iter().filter(|&&x| x < 0.0).count(),
            same.iter().filter(|&&x| x < -2.0).count(),
        ),
        different_misleading: (
            different.iter().filter(|p| p.log10_lr > 0.0).count(),
            different
                .iter()
                .filter(|p| p.log10_lr > 2.0 && class(p, p.stock_a) != class(p, p.stock_b))
                .count(),
        ),
        by_classes,
        search,
        medians: (median(same), median(different_lr)),
        per_draw,
    };
    Ok((figures, pairs))
}

/// Misleading evidence for different stocks by pair of classes: (class a, class b,
/// pairs with LR > 1, pairs), in the classes' order.
fn by_classes(campaign: &Campaign, different: &[&Pair]) -> Vec<(Class, Class, usize, usize)> {
    let class = |p: &Pair, stock: usize| campaign.stocks[p.draw][stock].class;
    let mut by_classes: Vec<(Class, Class, usize, usize)> = Vec::new();
    for p in different {
        let (mut a, mut b) = (class(p, p.stock_a), class(p, p.stock_b));
        if a.name() > b.name() {
            std::mem::swap(&mut a, &mut b);
        }
        let misleading = usize::from(p.log10_lr > 0.0);
        match by_classes
            .iter_mut()
            .find(|(x, y, _, _)| *x == a && *y == b)
        {
            Some(row) => {
                row.2 += misleading;
                row.3 += 1;
            }
            None => by_classes.push((a, b, misleading, 1)),
        }
    }
    by_classes.sort_by(|x, y| (x.0.name(), x.1.name()).cmp(&(y.0.name(), y.1.name())));
    by_classes
}

/// How the sheets' spots were used.
fn spot_use(sheets: &[&MeasuredSheet]) -> SpotUse {
    let mut spot_use = SpotUse::default();
    for s in sheets {
        spot_use.sheets += 1;
        spot_use.measured += s.measured_spots;
        spot_use.replaced += s.measured_spots.saturating_sub(s.planned);
        spot_use.excluded += s.excluded;
        spot_use.no_clean_spot += usize::from(s.no_clean_spot);
        spot_use.short += usize::from(s.measured.spots.len() < s.planned);
    }
    spot_use
}

/// The named pairs of reference papers over every draw (see [`Figures::named`]).
fn named_pairs(
    campaign: &Campaign,
    pairs: &[Pair],
) -> Vec<(&'static str, &'static str, usize, usize, f64)> {
    let name = |p: &Pair, k: usize| campaign.stocks[p.draw][k].name.as_str();
    NAMED_PAIRS
        .iter()
        .map(|&(a, b)| {
            let lrs: Vec<f64> = pairs
                .iter()
                .filter(|p| {
                    (name(p, p.stock_a), name(p, p.stock_b)) == (a, b)
                        || (name(p, p.stock_a), name(p, p.stock_b)) == (b, a)
                })
                .map(|p| p.log10_lr)
                .collect();
            (
                a,
                b,
                lrs.len(),
                lrs.iter().filter(|&&x| x < -2.0).count(),
                lrs.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            )
        })
        .collect()
}

fn percent(k: usize, n: usize) -> f64 {
    100.0 * k as f64 / n.max(1) as f64
}

/// "k of n (r %, 95 % CI a–b %)".
fn rate_with_interval(k: usize, n: usize) -> String {
    let (lo, hi) = wilson(k, n);
    format!(
        "{k} of {n} ({:.2} %; 95 % CI {:.2}–{:.2} %)",
        percent(k, n),
        100.0 * lo,
        100.0 * hi
    )
}

/// The claims of issue 25, checked on the figures pooled over the draws: each with whether
/// it held. Rates are judged on the pooled rate; the Wilson interval is stated with it
/// (it treats the pooled trials as independent, though trials of one draw share its
/// stocks: the per-draw table shows how much the draws differ). A decade is judged by
/// whether the reported value lies within 1 of its observed ratio's 95 % interval.
pub fn claims(f: &Figures) -> Vec<(String, bool)> {
    let (same_n, diff_n) = f.pairs;
    let judged: Vec<&Decade> = f
        .bins
        .iter()
        .filter(|b| b.same + b.different >= BIN_MIN_PAIRS)
        .collect();
    let worst_bin = judged.iter().map(|b| b.miss()).fold(0.0, f64::max);
    let mut out = vec![
        (
            format!(
                "reported log10 LRs outside their library's ELUB bounds: {} of {} (bounds from [{:+.2}, {:+.2}] to [{:+.2}, {:+.2}])",
                f.outside_bounds,
                same_n + diff_n,
                f.bounds_range.0.0,
                f.bounds_range.0.1,
                f.bounds_range.1.0,
                f.bounds_range.1.1
            ),
            f.outside_bounds == 0,
        ),
        (
            format!(
                "same-stock pairs with LR < 1/100: {} ≤ 1 %",
                rate_with_interval(f.strong_misleading.0, same_n)
            ),
            f.strong_misleading.0 as f64 <= 0.01 * same_n as f64,
        ),
        (
            format!(
                "different-stock pairs with LR > 100: {} ≤ 1 %",
                rate_with_interval(f.strong_misleading.1, diff_n)
            ),
            f.strong_misleading.1 as f64 <= 0.01 * diff_n as f64,
        ),
        (
            format!(
                "in every reported decade of ≥ {BIN_MIN_PAIRS} pairs ({} decades), the observed log10 same:different ratio (its 95 % interval) within 1 of the reported (the worst {worst_bin:.2} beyond)",
                judged.len()
            ),
            worst_bin <= 1.0,
        ),
        (
            format!(
                "Cllr {:.3} ≤ 0.3 where Cllr_min ≤ 0.2 (Cllr_min {:.3}; the model's raw ratios {:.3})",
                f.cllr, f.cllr_min, f.cllr_raw
            ),
            f.cllr_min > 0.2 || f.cllr <= 0.3,
        ),
    ];
    if f.instrument_pairs.0 > 0 {
        out.push((
            format!(
                "pairs measured on different instruments that say so: {} of {}",
                f.instrument_pairs.1, f.instrument_pairs.0
            ),
            f.instrument_pairs.1 == f.instrument_pairs.0,
        ));
    }
    out
}

/// The spots study's table: one row per number of spots per sheet.
pub(crate) fn spots_table(study: &[Figures]) -> String {
    let mut s = String::from(
        "| spots per sheet | Cllr (bits) | Cllr_min | median log10 LR, same stock | same-stock LR < 1 | different-stock LR > 1 | search rank-1 (95 % CI) | worst draw's search rank-1 | spots measured per sheet | device s per sheet |\n|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    for f in study {
        let (lo, hi) = wilson(f.search.0, f.search.1);
        let worst = f
            .per_draw
            .iter()
            .map(|d| percent(d.search.0, d.search.1))
            .reduce(f64::min)
            .unwrap_or(f64::NAN);
        let _ = writeln!(
            s,
            "| {} | {:.3} | {:.3} | {:+.2} | {} of {} | {:.2} % | {} of {}: {:.1} % ({:.1}–{:.1} %) | {worst:.1} % | {:.2} | {:.1} |",
            f.spots,
            f.cllr,
            f.cllr_min,
            f.medians.0,
            f.same_misleading.0,
            f.pairs.0,
            percent(f.different_misleading.0, f.pairs.1),
            f.search.0,
            f.search.1,
            percent(f.search.0, f.search.1),
            100.0 * lo,
            100.0 * hi,
            f.spot_use.measured as f64 / f.spot_use.sheets.max(1) as f64,
            f.device_seconds_per_sheet,
        );
    }
    s
}

/// `summary.md`: the claims' figures pooled over the draws, each draw's row, and the spots
/// study (`study`: the figures of each number of spots; may be empty).
pub fn summary_markdown(f: &Figures, study: &[Figures]) -> String {
    let mut s = String::new();
    let (stocks, library, held, spots) = f.counts;
    let _ = writeln!(
        s,
        "# Forensic validation ({}): {} draws of {stocks} stocks, {library} library sheets, {held} held-out sheets of {} planned spots, {spots} spots accepted\n",
        f.scenario, f.draws, f.spots
    );
    if let Some(scenario) = Scenario::named(f.scenario) {
        let _ = writeln!(
            s,
            "The world drawn: {}. The evidence is not told: each draw's population is estimated and validated from that draw's library sheets (`gonio forensic --library`'s procedure), and the held-out pairs are weighed against it.\n",
            scenario.about
        );
    }
    pooled_markdown(&mut s, f);
    let _ = writeln!(
        s,
        "\n## Calibration by reported decade\n\n| reported log10 LR | same-stock pairs | different-stock pairs | mean reported | observed (½ added to each count) | its 95 % interval |\n|---|---:|---:|---:|---:|---|"
    );
    for b in &f.bins {
        let _ = writeln!(
            s,
            "| [{:+.0}, {:+.0}) | {} | {} | {:+.2} | {:+.2} | [{:+.2}, {:+.2}] |",
            b.from,
            b.from + 1.0,
            b.same,
            b.different,
            b.reported,
            b.observed,
            b.observed_interval.0,
            b.observed_interval.1
        );
    }
    draws_markdown(&mut s, f);
    let _ = writeln!(
        s,
        "\n## Misleading evidence for different stocks, by pair of classes\n"
    );
    let _ = writeln!(
        s,
        "| classes | pairs | LR > 1 | rate |\n|---|---:|---:|---:|"
    );
    for (a, b, misleading, n) in &f.by_classes {
        let _ = writeln!(
            s,
            "| {} – {} | {n} | {misleading} | {:.2} % |",
            a.name(),
            b.name(),
            percent(*misleading, *n)
        );
    }
    if !study.is_empty() {
        let _ = writeln!(s, "\n## Spots per sheet\n");
        let _ = writeln!(
            s,
            "The same sheets (the same seeds) measured with each number of spots, library and held-out alike, over the {} draws.\n",
            f.draws
        );
        s += &spots_table(study);
    }
    let _ = writeln!(s, "\n## Claims\n");
    for (claim, held) in claims(f) {
        let _ = writeln!(s, "- {} {claim}", if held { "✓" } else { "✗" });
    }
    s
}

/// The summary's table of the claims' figures pooled over the draws.
fn pooled_markdown(s: &mut String, f: &Figures) {
    let u = &f.spot_use;
    let _ = writeln!(s, "| measure | value |\n|---|---|");
    let _ = writeln!(s, "| same-stock pairs | {} |", f.pairs.0);
    let _ = writeln!(s, "| different-stock pairs | {} |", f.pairs.1);
    let _ = writeln!(s, "| Cllr (bits) | {:.3} |", f.cllr);
    let _ = writeln!(s, "| Cllr_min (bits, after PAV) | {:.3} |", f.cllr_min);
    let _ = writeln!(s, "| median log10 LR, same stock | {:+.2} |", f.medians.0);
    let _ = writeln!(
        s,
        "| median log10 LR, different stocks | {:+.2} |",
        f.medians.1
    );
    let _ = writeln!(
        s,
        "| same-stock pairs with LR < 1 (misleading) | {} |",
        rate_with_interval(f.same_misleading.0, f.pairs.0)
    );
    let _ = writeln!(
        s,
        "| same-stock pairs with log10 LR < −2 | {} |",
        f.same_misleading.1
    );
    let _ = writeln!(
        s,
        "| different-stock pairs with LR > 1 (misleading) | {} |",
        rate_with_interval(f.different_misleading.0, f.pairs.1)
    );
    let _ = writeln!(
        s,
        "| different-class pairs with log10 LR > 2 | {} |",
        f.different_misleading.1
    );
    let _ = writeln!(
        s,
        "| library search: own stock ranked first | {} |",
        rate_with_interval(f.search.0, f.search.1)
    );
    let _ = writeln!(
        s,
        "| spots measured (of {} planned) | {} ({} replacements of flagged spots) |",
        u.sheets * f.spots,
        u.measured,
        u.replaced
    );
    let _ = writeln!(s, "| spots excluded (flagged) | {} |", u.excluded);
    let _ = writeln!(
        s,
        "| sheets short of their planned spots / with no clean spot | {} / {} |",
        u.short, u.no_clean_spot
    );
    let _ = writeln!(
        s,
        "| device time per sheet (s) | {:.0} |",
        f.device_seconds_per_sheet
    );
}

/// The summary's row of each draw of the population.
fn draws_markdown(s: &mut String, f: &Figures) {
    let _ = writeln!(s, "\n## Each draw of the population\n");
    let _ = writeln!(
        s,
        "Distances in between-stock standard deviations (10 %) over σ, ρs and ρd together (two stocks drawn about one paper are 2.3 apart on average, a drawn stock and its paper 1.6); close pairs: pairs of the draw's stocks closer than {} and {}; farthest miss: the largest distance from a missed sheet's stock to the stock ranked above it.\n",
        CLOSE[0], CLOSE[1]
    );
    let _ = writeln!(
        s,
        "| draw | seed | Cllr | Cllr_min | same-stock LR < 1 | different-stock LR > 1 | search rank-1 | nearest stocks | distance | Δσ, Δρs, Δρd | close pairs (< {}, < {}) | farthest miss |",
        CLOSE[0], CLOSE[1]
    );
    let _ = writeln!(
        s,
        "|---:|---|---:|---:|---:|---:|---:|---|---:|---|---:|---:|"
    );
    for d in &f.per_draw {
        let (names, dist, diff, close) = match &d.nearest {
            Some(n) => (
                format!("{} – {}", n.stocks.0, n.stocks.1),
                format!("{:.2}", n.distance),
                format!(
                    "{:+.1} %, {:+.1} %, {:+.1} %",
                    n.difference_pct[0], n.difference_pct[1], n.difference_pct[2]
                ),
                format!("{}, {}", n.close_pairs[0], n.close_pairs[1]),
            ),
            None => ("–".into(), "–".into(), "–".into(), "–".into()),
        };
        let _ = writeln!(
            s,
            "| {} | {:#x} | {:.3} | {:.3} | {} of {} | {} of {} ({:.2} %) | {} of {} ({:.1} %) | {names} | {dist} | {diff} | {close} | {} |",
            d.draw,
            d.seed,
            d.cllr,
            d.cllr_min,
            d.same_misleading,
            d.pairs.0,
            d.different_misleading,
            d.pairs.1,
            percent(d.different_misleading, d.pairs.1),
            d.search.0,
            d.search.1,
            percent(d.search.0, d.search.1),
            d.farthest_miss
                .map_or("–".to_string(), |m| format!("{m:.2}")),
        );
    }
}

/// A Tippett plot: for each log10 LR x, the share of same-stock and of different-stock
/// pairs whose log10 LR exceeds x (every draw's pairs together).
pub fn tippett_svg(
    pairs: &[Pair],
    draws: usize,
    path: &std::path::Path,
) -> Result<(), ForensicError> {
    let (same, different) = split(pairs);
    let caption = if draws == 1 {
        "Tippett plot: held-out pairs".to_string()
    } else {
        format!("Tippett plot: held-out pairs of {draws} population draws")
    };
    tippett_svg_of(&same, &different, &caption, path)
}

/// A Tippett plot of same- and different-stock log10 LRs: the share of each above x.
pub fn tippett_svg_of(
    same: &[f64],
    different: &[f64],
    caption: &str,
    path: &std::path::Path,
) -> Result<(), ForensicError> {
    let (lo, hi) = (-10.0f64, 6.0f64);
    let curve = |values: &[f64]| -> Vec<(f64, f64)> {
        let n = values.len().max(1) as f64;
        (0..=320)
            .map(|k| lo + (hi - lo) * k as f64 / 320.0)
            .map(|x| (x, values.iter().filter(|&&v| v > x).count() as f64 / n))
            .collect()
    };
    let root = SVGBackend::new(path, (720, 460)).into_drawing_area();
    let draw = || -> Result<(), Box<dyn std::error::Error>> {
        root.fill(&WHITE)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(caption, ("sans-serif", 20))
            .margin(15)
            .x_label_area_size(45)
            .y_label_area_size(60)
            .build_cartesian_2d(lo..hi, 0.0..1.0)?;
        chart
            .configure_mesh()
            .x_desc("log10 LR (same stock : different stocks), x")
            .y_desc("share of pairs with log10 LR > x")
            .draw()?;
        chart
            .draw_series(LineSeries::new(curve(same), BLUE.stroke_width(2)))?
            .label(format!("same stock ({} pairs)", same.len()))
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLUE.stroke_width(2)));
        chart
            .draw_series(LineSeries::new(curve(different), RED.stroke_width(2)))?
            .label(format!("different stocks ({} pairs)", different.len()))
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], RED.stroke_width(2)));
        chart.draw_series(LineSeries::new(
            vec![(0.0, 0.0), (0.0, 1.0)],
            BLACK.mix(0.4),
        ))?;
        chart
            .configure_series_labels()
            .border_style(BLACK)
            .background_style(WHITE.mix(0.9))
            .position(SeriesLabelPosition::MiddleLeft)
            .draw()?;
        root.present()?;
        Ok(())
    };
    draw().map_err(|e| ForensicError::Draw {
        path: path.to_path_buf(),
        message: e.to_string(),
    })
}

/// The campaign's table: one row per scenario, the targets side by side.
pub fn campaign_markdown(campaign: &[Figures]) -> String {
    let mut s = String::from(
        "| scenario | pairs (same / different) | Cllr | Cllr_min | raw Cllr | bounds (narrowest) | outside bounds | same < 1/100 | different > 100 | worst decade beyond its interval | instrument pairs warned | claims |\n|---|---|---:|---:|---:|---|---:|---:|---:|---:|---|---|\n",
    );
    for f in campaign {
        let claims = claims(f);
        let worst = f
            .bins
            .iter()
            .filter(|b| b.same + b.different >= BIN_MIN_PAIRS)
            .map(Decade::miss)
            .fold(0.0, f64::max);
        let _ = writeln!(
            s,
            "| {} | {} / {} | {:.3} | {:.3} | {:.3} | [{:+.2}, {:+.2}] | {} | {} | {} | {worst:.2} | {} | {} of {} held |",
            f.scenario,
            f.pairs.0,
            f.pairs.1,
            f.cllr,
            f.cllr_min,
            f.cllr_raw,
            f.bounds_range.0.0,
            f.bounds_range.0.1,
            f.outside_bounds,
            f.strong_misleading.0,
            f.strong_misleading.1,
            if f.instrument_pairs.0 == 0 {
                "—".to_string()
            } else {
                format!("{} of {}", f.instrument_pairs.1, f.instrument_pairs.0)
            },
            claims.iter().filter(|c| c.1).count(),
            claims.len()
        );
    }
    s
}
