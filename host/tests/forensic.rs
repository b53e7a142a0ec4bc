//! The strength of the evidence (issue 13): the issue's own cases through whole simulated
//! sessions against the default population, and the forensic study in small (`gonio
//! forensic` runs it at full size, docs/FORENSIC.md).
use host::analysis::evidence::{self, Population, Sheet, Spot};
use host::analysis::model::{RHO_D, RHO_S, SIGMA};
use host::instrument::calibration::Tile;
use host::instrument::sim::{Physics, SimOptions};
use host::session::{Policy, PolicyChoice};
use host::study::{SimulatedRun, simulated_session};
use host::study::forensic::{self, Design};

/// One spot: a whole session of `sample` on the realistic instrument, the tile's
/// certificate stated as `tile_radiance_factor`.
fn spot(sample: &str, seed: u64, tile_radiance_factor: f64) -> Spot {
    let options = SimOptions { seed, physics: Physics::Real, sheet_variation: forensic::SPOT_VARIATION_PCT, ..SimOptions::default() };
    let run = SimulatedRun { sample, options: &options, policy: Policy::from(PolicyChoice::Adaptive), integration_ms: None };
    let tile = Tile::new(tile_radiance_factor, 0.5).expect("a tile");
    let (outcome, _) = simulated_session(&run, |session| session.with_tile(tile)).expect("a session");
    let f = &outcome.report.fit;
    let index = [SIGMA, RHO_S, RHO_D];
    Spot { values: index.map(|i| f.reported(i)), covariance: std::array::from_fn(|r| std::array::from_fn(|c| f.covariance[index[r]][index[c]])) }
}

/// A sheet measured at three spots (each session another spot of the stock, 3 % apart).
fn sheet(sample: &str, seed: u64) -> Sheet {
    sheet_with_tile(sample, seed, 0.99)
}

fn sheet_with_tile(sample: &str, seed: u64, tile_radiance_factor: f64) -> Sheet {
    Sheet { spots: (0..3).map(|k| spot(sample, seed * 10 + k, tile_radiance_factor)).collect() }
}

/// Today's `gonio compare` called two sessions of the same G sheet different stock in 20 %
/// of pairs, and a 0.5 % calibration difference in 52–100 %; J3 against J4 and PPC against
/// J3 must be told apart. Sheets of three spots (the issue's design: a sheet is several
/// spots), over several seeds each, against the default population.
#[test]
fn the_issues_cases_point_the_right_way() {
    let population = Population::default_population();
    for seed in [3, 4, 5] {
        let same = evidence::likelihood_ratio(&sheet("G", seed), &sheet("G", seed + 100), &population);
        assert!(same.log10_lr > 0.0, "seed {seed}: two sessions of one G sheet: {same:?}");
        // The second session's tile certificate 0.5 % off: every reading 0.5 % off.
        let calibrated_apart = evidence::likelihood_ratio(&sheet("G", seed), &sheet_with_tile("G", seed + 200, 0.99 * 1.005), &population);
        assert!(calibrated_apart.log10_lr > 0.0, "seed {seed}: a 0.5 % calibration difference: {calibrated_apart:?}");
        for (a, b) in [("J3", "J4"), ("PPC", "J3")] {
            let e = evidence::likelihood_ratio(&sheet(a, seed), &sheet(b, seed + 300), &population);
            assert!(e.log10_lr < -2.0, "seed {seed}: {a} vs {b}: {e:?}");
        }
        println!("seed {seed}: same G {:+.2}, 0.5 % apart {:+.2}", same.log10_lr, calibrated_apart.log10_lr);
    }
}

/// The forensic study in small: 32 stocks, 2 library and 2 held-out sheets of 2 spots each.
#[test]
fn a_small_population_validates_the_likelihood_ratios() {
    let design = Design::SMALL;
    let stocks = forensic::stocks(&design);
    assert_eq!(stocks.len(), 32);
    let threads = std::thread::available_parallelism().map_or(2, |n| n.get());
    let sheets = forensic::measure_all(&design, &stocks, threads, &|| {}).expect("every session");
    let (population, pairs) = forensic::pairs(&stocks, &sheets).expect("a population");
    let search = forensic::search_rank_one(&stocks, &sheets, &population);
    let f = forensic::figures(&stocks, &sheets, &pairs, search);
    print!("{}", forensic::summary_markdown(&f));
    assert_eq!(f.pairs.0, 32, "one same-stock pair per stock");
    assert!(f.cllr < 0.3, "Cllr {}", f.cllr);
    assert!(f.cllr_min <= f.cllr + 1e-12);
    assert_eq!(f.same_misleading.1, 0, "a same-stock pair with log10 LR < −2");
    assert_eq!(f.different_misleading.1, 0, "a different-class pair with log10 LR > 2");
    assert!(f.same_misleading.0 <= 2, "{} of 32 same-stock pairs misleading", f.same_misleading.0);
    // The issue's 95 % is not reached (docs/FORENSIC.md: stocks drawn within a few percent
    // of each other are confused); what is measured is held here.
    assert!(search.0 as f64 >= 0.75 * search.1 as f64, "search {search:?}");
}

#[test]
fn cllr_is_zero_for_a_perfect_system_one_for_an_uninformative_one_and_pav_never_worse() {
    assert!(forensic::cllr(&[10.0, 12.0], &[-10.0, -12.0]) < 1e-6);
    assert!((forensic::cllr(&[0.0, 0.0], &[0.0]) - 1.0).abs() < 1e-12);
    // Well-separated but badly calibrated: Cllr large, Cllr_min near 0.
    let (same, different) = ([-3.0, -2.5, -2.8], [-6.0, -7.0, -6.5]);
    assert!(forensic::cllr(&same, &different) > 1.0);
    assert!(forensic::cllr_min(&same, &different) < 0.05);
}
