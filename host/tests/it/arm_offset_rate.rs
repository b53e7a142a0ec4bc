//! The arm-offset test on readings without uncertainties (what `gonio fit` gets from a
//! table without a `std` column): its false-alarm rate on exact-TSL data sets, and its
//! power on a real offset. Issue 28: the HC3 sandwich's Wald statistic against χ²(1)
//! accepted offsets of 0.17–0.61° that were not there in 8 of 200 full-grid data sets
//! of the rough papers.
use crate::common::{self, Instrument, Sheet, draw, truth};
use host::analysis::fit::{FitOptions, fit};

/// The false-alarm rate the test is held to (its level is 1 %).
const TARGET_RATE: f64 = 0.02;
/// The chance that a test at [`TARGET_RATE`] fails this check anyway.
const CHECK_LEVEL: f64 = 0.01;

/// The smallest count k with P(X ≥ k) ≤ `level` for X ~ Binomial(n, p): a rate of at most
/// p gives k alarms or more in n data sets less often than `level`.
fn binomial_bound(n: usize, p: f64, level: f64) -> usize {
    // P(X = j) by the recurrence from P(X = 0); upper tail = 1 − lower.
    let mut pmf = (1.0 - p).powi(n as i32);
    let mut below = 0.0;
    for k in 0..=n {
        if 1.0 - below <= level {
            return k;
        }
        below += pmf;
        pmf *= (n - k) as f64 / (k + 1) as f64 * p / (1.0 - p);
    }
    n + 1
}

#[test]
fn the_binomial_bound_is_the_upper_tail() {
    // Binomial(100, 0.02): P(X ≥ 6) = 0.0155, P(X ≥ 7) = 0.0041.
    assert_eq!(binomial_bound(100, 0.02, 0.01), 7);
    // Binomial(10, ½): P(X ≥ 5) = 0.623, P(X ≥ 6) = 0.377.
    assert_eq!(binomial_bound(10, 0.5, 0.5), 6);
}

/// 1,056 exact-TSL data sets without uncertainties, the issue's noise (1 % + 0.003), all
/// eight papers: 128 on the 284-geometry benchmark grid, 128 on Strategy 2 at δ = 2° (51
/// geometries), 800 on Strategy 1's 12 geometries (cheap, and where the old test was
/// worst). On each schedule an offset is fitted in no more than a rate of 2 % allows at
/// the 1 % level. Before the noise was modelled: 31 of the 800 Strategy 1 sets (SG 14 of
/// 100; the equal-noise likelihood ratio on peak readings 50 times noisier than the
/// flanks), over the bound of 27.
#[test]
fn without_uncertainties_an_offset_that_is_not_there_is_seldom_fitted() {
    let mut lines = Vec::new();
    let (mut alarms, mut sets) = (0, 0);
    for (label, geometries, seeds) in [
        ("full grid", common::full_grid(), 16),
        ("strategy 2, δ = 2°", common::strategy2(2), 16),
        ("strategy 1, M = 12", common::strategy1_m12(), 100),
    ] {
        let (mut here, mut count) = (Vec::new(), 0);
        for (k, name) in ["G", "SG", "PPC", "MC", "J1", "J2", "J3", "J4"]
            .into_iter()
            .enumerate()
        {
            let p = common::reference(name);
            for seed in 0..seeds {
                // Each paper its own noise: the rough papers' lobes are alike, and one
                // draw of noise on all of them is nearly one data set, not five (the
                // bound counts independent ones).
                let seed = 50_000 + 1000 * k as u64 + seed;
                let obs = common::noisy(&p, &geometries, seed);
                let result = fit(&obs, &FitOptions::default()).expect("valid");
                count += 1;
                if let Some(offset) = result.arm_offset {
                    here.push(format!(
                        "{name} seed {seed}: δ0 {:+.3}° (statistic {:.2})",
                        offset.deg, offset.lr
                    ));
                }
            }
        }
        let bound = binomial_bound(count, TARGET_RATE, CHECK_LEVEL);
        lines.push(format!(
            "{label}: {} of {count} (bound {bound}) {here:?}",
            here.len()
        ));
        assert!(here.len() < bound, "{label}: {}", lines.join("\n"));
        alarms += here.len();
        sets += count;
    }
    let bound = binomial_bound(sets, TARGET_RATE, CHECK_LEVEL);
    eprintln!("{alarms} of {sets} (bound {bound})\n{}", lines.join("\n"));
    assert!(alarms < bound, "{alarms} of {sets}:\n{}", lines.join("\n"));
}

/// A real offset without uncertainties: 1° and 0.5° on G and SG (full grid and Strategy 2
/// at δ = 2°, the issue's noise) is found in most seeds, and where found it is close.
#[test]
fn without_uncertainties_a_real_offset_is_found() {
    let seeds = 8u64;
    let mut lines = Vec::new();
    for offset_deg in [1.0, 0.5] {
        let instrument = Instrument {
            arm_offset_deg: offset_deg,
            with_std: false,
            ..Instrument::issue()
        };
        for name in ["G", "SG"] {
            let p = common::reference(name);
            for (label, geometries) in [
                ("full grid", common::full_grid()),
                ("strategy 2, δ = 2°", common::strategy2(2)),
            ] {
                let t = truth(&Sheet::ideal(p), &geometries, &instrument);
                let mut found = Vec::new();
                for seed in 0..seeds {
                    let (obs, _) = draw(&t, &instrument, 29_000 + seed);
                    let result = fit(&obs, &FitOptions::default()).expect("valid");
                    if let Some(offset) = result.arm_offset {
                        found.push(offset.deg);
                    }
                }
                let line = format!(
                    "{offset_deg}° on {name}, {label}: found in {} of {seeds}, δ0 {found:.3?}",
                    found.len()
                );
                assert!(found.len() * 4 >= seeds as usize * 3, "{line}");
                assert!(found.iter().all(|d| (d - offset_deg).abs() < 0.1), "{line}");
                lines.push(line);
            }
        }
    }
    eprintln!("{}", lines.join("\n"));
}

/// An arm offset beyond the 3° the fit looks for (a broken arm, or a shape of the sheet
/// the model does not hold, seen as a shift): the fit keeps the offset at the limit and
/// says so, flagged lack-of-fit, never a clean result. Offsets inside the range are fitted
/// without that note. J1 (a lobe wide enough for a 4.5° shift to be fitted away in part)
/// and G, the issue's noise with uncertainties, the full grid, three seeds each.
#[test]
fn an_offset_at_the_limit_of_the_search_is_not_a_clean_result() {
    let at_limit = |r: &host::analysis::fit::FitResult| {
        r.notes
            .iter()
            .any(|n| matches!(n, host::analysis::fit::Note::ArmOffsetAtLimit { .. }))
    };
    for name in ["G", "J1"] {
        let p = common::reference(name);
        for offset_deg in [4.5, -4.5, 1.0] {
            let instrument = Instrument {
                arm_offset_deg: offset_deg,
                ..Instrument::issue()
            };
            let t = truth(&Sheet::ideal(p), &common::full_grid(), &instrument);
            for seed in 0..3 {
                let (obs, _) = draw(&t, &instrument, 31_000 + seed);
                let result = fit(&obs, &FitOptions::default()).expect("valid");
                let fitted = result.arm_offset.as_ref().map(|o| o.deg);
                let line = format!("{name}, {offset_deg}°, seed {seed}: δ0 {fitted:?}");
                if offset_deg.abs() > 3.0 {
                    assert_eq!(fitted.map(|d| d.abs()), Some(3.0), "{line}");
                    assert!(at_limit(&result), "{line}: {:?}", result.notes);
                    assert!(
                        result
                            .flags
                            .contains(&host::analysis::flags::Flag::LackOfFit),
                        "{line}"
                    );
                } else {
                    // Found, and near (J1's broad peak places it to about 0.1°).
                    assert!(
                        fitted.is_some_and(|d| (d - offset_deg).abs() < 0.25),
                        "{line}"
                    );
                    assert!(!at_limit(&result), "{line}: {:?}", result.notes);
                }
            }
        }
    }
}
