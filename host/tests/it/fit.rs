//! The fit engine: global minimum against brute force, weighting, intervals,
//! identifiability, and errors on bad input.
use crate::common;
use host::analysis::fit::{self, Bound, FitError, FitOptions, Note, Observation, fit};
use host::analysis::model::{self, Params};

fn no_acceptance() -> FitOptions {
    FitOptions {
        acceptance_deg: None,
        ..FitOptions::default()
    }
}

/// min over a dense (σ, η) grid of the cost with ρs, ρd solved linearly at each point.
fn brute_force_min(obs: &[Observation]) -> (f64, f64, f64) {
    let mut best = (f64::INFINITY, 0.0, 0.0);
    let profile = fit::LinearProfile::new(obs, None).expect("valid data");
    let n_sigma = 600;
    let n_eta = 80;
    for i in 0..n_sigma {
        // 0.01° … 90°, log-spaced: about 1.5 % apart.
        let sigma = 0.01 * (9000f64).powf(i as f64 / (n_sigma - 1) as f64);
        for j in 0..n_eta {
            // Dense near 1, where F changes fastest.
            let eta = 1.0 + 2.0 * (j as f64 / (n_eta - 1) as f64).powi(2);
            let s = profile.at(sigma, eta);
            if s.cost < best.0 {
                best = (s.cost, sigma, eta);
            }
        }
    }
    best
}

#[test]
fn finds_the_global_minimum_of_multimodal_glossy_problems() {
    let cases = [
        ("G", common::full_grid(), 1),
        ("SG", common::full_grid(), 2),
        ("G", common::strategy2(3), 3),
        ("SG", common::strategy2(5), 4),
        ("G", common::strategy2(2), 5),
        ("SG", common::strategy1_m12(), 6),
        ("J2", common::strategy1_m12(), 7),
        ("MC", common::strategy2(10), 8),
    ];
    for (name, geometries, seed) in cases {
        let obs = common::synthetic(
            &common::reference(name),
            &geometries,
            0.0,
            0.01,
            0.003,
            seed,
            false,
        );
        let result = fit(&obs, &no_acceptance()).expect("valid data");
        // The engine's cost on the full model: what it found before any reduction is at
        // least as good as the reported one; compare the reported (reduced) model's cost.
        let (brute, bs, be) = brute_force_min(&obs);
        println!(
            "{name} n={}: fit cost {:.6e} (σ {:.4} η {:.4}) brute force {brute:.6e} (σ {bs:.4} η {be:.4}) notes {:?}",
            obs.len(),
            result.cost,
            result.params.sigma_deg,
            result.params.eta,
            result.notes
        );
        let tolerance = 1e-6 * brute + 1e-12;
        assert!(
            result.cost <= brute + tolerance,
            "{name} n={}: fit {} > brute force {brute}",
            obs.len(),
            result.cost
        );
    }
}

#[test]
fn noise_free_data_is_recovered_exactly() {
    for r in host::analysis::classify::REFERENCES {
        let obs = common::synthetic(&r.params, &common::full_grid(), 0.0, 0.0, 0.0, 0, false);
        let result = fit(&obs, &no_acceptance()).expect("valid data");
        let p = result.params;
        assert!(
            (p.sigma_deg / r.params.sigma_deg - 1.0).abs() < 1e-6,
            "{}: {p:?}",
            r.name
        );
        assert!(
            (p.rho_d / r.params.rho_d - 1.0).abs() < 1e-6,
            "{}: {p:?}",
            r.name
        );
        assert!(result.nmae < 1e-6, "{}: NMAE {}", r.name, result.nmae);
        assert_eq!(result.status, fit::Status::Converged);
    }
}

#[test]
fn confidence_intervals_cover_the_truth_and_bounds_are_reported() {
    let mut covered = 0;
    let mut total = 0;
    for (k, r) in host::analysis::classify::REFERENCES.iter().enumerate() {
        for seed in 0..5u64 {
            let obs = common::synthetic(
                &r.params,
                &common::full_grid(),
                0.0,
                0.01,
                0.003,
                1000 + 10 * k as u64 + seed,
                true,
            );
            let result = fit(&obs, &no_acceptance()).expect("valid data");
            assert!(result.weighted);
            let truth = r.params.to_array();
            for i in 0..3 {
                let (low, high) = result.ci95[i].expect("σ, ρs, ρd are fitted");
                let value = result.params.to_array()[i];
                assert!(
                    low <= value && value <= high,
                    "{} param {i}: {value} not in [{low}, {high}]",
                    r.name
                );
                total += 1;
                if low <= truth[i] && truth[i] <= high {
                    covered += 1;
                }
            }
            if result
                .notes
                .iter()
                .any(|n| matches!(n, Note::EtaAtBound { eta, .. } if *eta == 3.0))
            {
                assert!(
                    result
                        .active_bounds
                        .iter()
                        .any(|b| b.param == "eta" && b.bound == Bound::Upper)
                );
                assert!(!result.model.0[model::ETA] && result.ci95[model::ETA].is_none());
                assert_eq!(result.reported(model::ETA), Some(3.0));
            }
        }
    }
    let share = covered as f64 / total as f64;
    println!("95 % intervals covered the truth {covered}/{total} = {share:.3}");
    assert!(share > 0.85, "coverage {share}");
}

#[test]
fn weights_follow_the_given_uncertainties() {
    let p = common::reference("PPC");
    let geometries = common::full_grid();
    let mut obs = common::synthetic(&p, &geometries, 0.0, 0.01, 0.003, 9, true);
    let clean = fit(&obs, &no_acceptance()).expect("valid");
    // A wild reading with an honest, huge uncertainty barely moves the fit...
    obs[100].radiance_factor *= 3.0;
    obs[100].std = Some(100.0);
    let weighted = fit(&obs, &no_acceptance()).expect("valid");
    assert!((weighted.params.sigma_deg / clean.params.sigma_deg - 1.0).abs() < 1e-3);
    // ...while the same reading unweighted pulls it.
    let unweighted: Vec<Observation> = obs
        .iter()
        .map(|o| Observation { std: None, ..*o })
        .collect();
    let pulled = fit(&unweighted, &no_acceptance()).expect("valid");
    let d_weighted = (weighted.params.rho_d - clean.params.rho_d).abs();
    let d_unweighted = (pulled.params.rho_d - clean.params.rho_d).abs();
    assert!(
        d_unweighted > 10.0 * d_weighted,
        "{d_unweighted} vs {d_weighted}"
    );
}

#[test]
fn lambertian_data_fits_only_rho_d() {
    let p = Params {
        sigma_deg: 10.0,
        rho_s: 0.0,
        rho_d: 0.7,
        eta: 1.5,
    };
    let obs = common::synthetic(&p, &common::full_grid(), 0.0, 0.01, 0.003, 3, false);
    let result = fit(&obs, &FitOptions::default()).expect("valid");
    assert!(
        result.notes.contains(&Note::NoSpecularTerm),
        "{:?}",
        result.notes
    );
    assert_eq!(result.model.names(), ["rho_d"]);
    assert_eq!(result.sigma_deg(), None);
    assert_eq!(result.reported(model::ETA), None);
    assert!((result.params.rho_d - 0.7).abs() < 0.01);
    assert!(result.ci95[model::RHO_D].is_some());
}

#[test]
fn unresolved_peak_is_reported_as_an_upper_limit() {
    // G from Strategy 1's 12 geometries: nothing samples the 4° wide peak but its top.
    let obs = common::noisy(&common::reference("G"), &common::strategy1_m12(), 21);
    let result = fit(&obs, &FitOptions::default()).expect("valid");
    let upper = result.sigma_upper_deg().expect("σ is unresolved at M = 12");
    println!(
        "G at M = 12: σ ≤ {upper:.3}°, notes {:?}, model {:?}",
        result.notes,
        result.model.names()
    );
    assert!((0.8..10.0).contains(&upper), "{upper}");
    assert_eq!(result.sigma_deg(), None);
    assert!(!result.model.0[model::SIGMA]);
    assert!(result.ci95[model::SIGMA].is_none());
}

fn valid() -> Vec<Observation> {
    common::synthetic(
        &common::reference("PPC"),
        &common::strategy1_m12(),
        0.0,
        0.0,
        0.0,
        0,
        false,
    )
}

#[test]
fn bad_input_gets_a_clear_error() {
    let opts = FitOptions::default();
    // Fewer geometries than parameters (repeats do not count).
    let few: Vec<Observation> = valid()
        .into_iter()
        .take(3)
        .chain(valid().into_iter().take(1))
        .collect();
    assert!(matches!(
        fit(&few, &opts),
        Err(FitError::TooFewGeometries {
            found: 3,
            needed: 4
        })
    ));
    // NaN.
    let mut o = valid();
    o[5].radiance_factor = f64::NAN;
    assert_eq!(
        fit(&o, &opts).unwrap_err(),
        FitError::NotFinite {
            index: 5,
            what: "radiance_factor"
        }
    );
    // Negative.
    let mut o = valid();
    o[2].radiance_factor = -0.1;
    let e = fit(&o, &opts).unwrap_err();
    assert_eq!(e.reading_index(), Some(2));
    assert!(e.to_string().contains("negative"), "{e}");
    // All equal.
    let o: Vec<Observation> = valid()
        .into_iter()
        .map(|o| Observation {
            radiance_factor: 0.5,
            ..o
        })
        .collect();
    assert!(matches!(fit(&o, &opts), Err(FitError::AllEqual { .. })));
    // Conflicting duplicates; agreeing repeats are fine.
    let mut o = valid();
    let mut again = o[4];
    again.radiance_factor *= 1.01;
    o.push(again);
    assert!(fit(&o, &opts).is_ok());
    again.radiance_factor *= 2.0;
    o.push(again);
    let e = fit(&o, &opts).unwrap_err();
    assert!(
        matches!(e, FitError::ConflictingDuplicates { index: 13, .. }),
        "{e}"
    );
    // Angles outside [0°, 90°): 90° itself too, where G/(cos·cos) is unbounded.
    for (ti, tr) in [
        (-1.0, 10.0),
        (20.0, 90.5),
        (f64::INFINITY, 0.0),
        (90.0, 10.0),
        (20.0, 90.0),
    ] {
        let mut o = valid();
        o[7].theta_i_deg = ti;
        o[7].theta_r_deg = tr;
        let e = fit(&o, &opts).unwrap_err();
        assert_eq!(e.reading_index(), Some(7), "{e}");
    }
    let mut o = valid();
    o[7].theta_r_deg = 90.0;
    let e = fit(&o, &opts).unwrap_err();
    assert!(e.to_string().contains("[0°, 90°)"), "{e}");
    // Values that would overflow the squares and weights: refused with the limit named.
    let mut o = valid();
    o[3].radiance_factor = 1e308;
    let e = fit(&o, &opts).unwrap_err();
    assert!(matches!(e, FitError::TooLarge { index: 3, .. }), "{e}");
    let mut o: Vec<Observation> = valid()
        .into_iter()
        .map(|o| Observation {
            std: Some(0.01),
            ..o
        })
        .collect();
    o[6].std = Some(1e-300);
    let e = fit(&o, &opts).unwrap_err();
    assert!(
        matches!(e, FitError::UncertaintyOutOfRange { index: 6, .. }),
        "{e}"
    );
    // At the limits the fit is finite.
    let mut o: Vec<Observation> = valid()
        .into_iter()
        .map(|o| Observation {
            std: Some(fit::STD_MIN),
            ..o
        })
        .collect();
    o[0].radiance_factor = fit::RADIANCE_FACTOR_MAX;
    let at_limits = fit(&o, &opts).expect("valid at the limits");
    assert!(
        at_limits.cost.is_finite() && at_limits.params.to_array().iter().all(|v| v.is_finite())
    );
    // Uncertainties.
    let mut o = valid();
    o[0].std = Some(0.0);
    assert!(matches!(
        fit(&o, &opts),
        Err(FitError::BadUncertainty { index: 0, .. })
    ));
    let mut o: Vec<Observation> = valid()
        .into_iter()
        .map(|o| Observation {
            std: Some(0.01),
            ..o
        })
        .collect();
    o[3].std = None;
    assert!(matches!(
        fit(&o, &opts),
        Err(FitError::MixedUncertainties { index: 3 })
    ));
}

#[test]
fn extreme_but_valid_data_gives_finite_results() {
    // Grazing angles, a zero reading, and a huge peak: finite numbers, no panic.
    let p = Params {
        sigma_deg: 0.05,
        rho_s: 1e4,
        rho_d: 0.0,
        eta: 3.0,
    };
    let geometries = [
        (0.0, 0.0),
        (89.99, 89.99),
        (85.0, 85.0),
        (89.99, 0.0),
        (45.0, 45.0),
        (45.0, 50.0),
        (10.0, 80.0),
    ];
    let obs: Vec<Observation> = geometries
        .iter()
        .map(|&(ti, tr)| Observation {
            theta_i_deg: ti,
            theta_r_deg: tr,
            radiance_factor: model::radiance_factor(&p, ti, tr).min(fit::RADIANCE_FACTOR_MAX),
            std: None,
            theta_r_span_deg: 0.0,
        })
        .collect();
    let result = fit(&obs, &FitOptions::default()).expect("valid");
    assert!(result.params.to_array().iter().all(|v| v.is_finite()));
    assert!(result.nmae.is_finite() && result.rms.is_finite());
}

// ---------------------------------------------------------------------------------------
// Goodness of fit, shared errors and what was not determined (issue 12). Campaigns: each
// case's noise-free readings are computed once and the noise drawn per seed.

use common::{Instrument, Lobe, Sheet, covers, draw, truth};
use host::analysis::classify::{Class, REFERENCES, classify};
use host::analysis::flags::Flag;
use host::analysis::result;

fn class_of_reference(name: &str) -> Class {
    REFERENCES
        .iter()
        .find(|r| r.name == name)
        .expect("a Table 6 paper")
        .class
}

/// A G or SG sheet whose lobe is GGX or Cauchy of the same FWHM: with uncertainties the
/// fit says so every time (`lack-of-fit`, or the heavy-tailed lobe named and
/// `model-extended`); with or without them it is never confidently wrong (before either:
/// SG with confidence 1.00 and no flag).
#[test]
fn non_gaussian_lobes_are_flagged_and_never_confidently_wrong() {
    let mut summary = Vec::new();
    for name in ["G", "SG"] {
        for lobe in [Lobe::Ggx, Lobe::Cauchy] {
            for (label, geometries) in [
                ("full grid", common::full_grid()),
                ("strategy 2, δ = 2°", common::strategy2(2)),
            ] {
                for with_std in [true, false] {
                    let instrument = Instrument {
                        with_std,
                        ..Instrument::issue()
                    };
                    let sheet = Sheet {
                        params: common::reference(name),
                        lobe,
                        bump: None,
                    };
                    let t = truth(&sheet, &geometries, &instrument);
                    let seeds = if with_std { 15 } else { 8 };
                    let (mut flagged, mut right, mut confidently_wrong) = (0, 0, 0);
                    for seed in 0..seeds {
                        let (obs, _) = draw(&t, &instrument, 3000 + seed);
                        let result = fit(&obs, &FitOptions::default()).expect("valid");
                        let c = classify(&result);
                        // Said: flagged, or a term named for the shape (the extension).
                        flagged += usize::from(
                            result.lack_of_fit || result.flags.contains(&Flag::ModelExtended),
                        );
                        right += usize::from(c.class == Some(class_of_reference(name)));
                        if c.class.is_some_and(|k| k != class_of_reference(name))
                            && c.confidence >= 0.95
                        {
                            confidently_wrong += 1;
                        }
                        if result.lack_of_fit {
                            assert!(result.flags.contains(&Flag::LackOfFit));
                            assert!(
                                c.confidence
                                    <= host::analysis::classify::LACK_OF_FIT_CONFIDENCE_CAP
                            );
                            assert!(
                                result.variance_scale > 1.0,
                                "a flagged fit's intervals are widened"
                            );
                        }
                    }
                    summary.push(format!("{name} {lobe:?} {label} std {with_std}: flagged {flagged}/{seeds}, class right {right}/{seeds}"));
                    assert_eq!(
                        confidently_wrong, 0,
                        "{name} {lobe:?} {label} std {with_std}: a wrong class with confidence ≥ 0.95"
                    );
                    if with_std {
                        assert_eq!(
                            flagged as u64, seeds,
                            "{name} {lobe:?} {label}: the lobe's shape went unsaid"
                        );
                    }
                }
            }
        }
    }
    println!("{}", summary.join("\n"));
}

/// On ideal data (the model's own shape, the instrument's noise and window) `lack-of-fit`
/// is raised in at most 2 % of 520 fits across the papers and schedules (the stated level
/// is 1 %: χ² and the structure test at 0.5 % each).
#[test]
fn lack_of_fit_false_flag_rate_on_ideal_data() {
    type Case = (&'static str, Vec<(f64, f64)>, Instrument, u64);
    let mut cases: Vec<Case> = Vec::new();
    for r in &REFERENCES {
        cases.push((r.name, common::full_grid(), Instrument::issue(), 25));
        cases.push((r.name, common::full_grid(), Instrument::quiet(), 15));
    }
    for name in ["G", "SG"] {
        cases.push((name, common::strategy2(2), Instrument::issue(), 40));
        cases.push((name, common::strategy2(5), Instrument::quiet(), 30));
    }
    for name in ["PPC", "J1"] {
        cases.push((name, common::strategy1_m12(), Instrument::issue(), 20));
    }
    let (mut fits, mut flagged, mut chi2_flags, mut structure_flags) = (0, 0, 0, 0);
    for (k, (name, geometries, instrument, seeds)) in cases.iter().enumerate() {
        let t = truth(
            &Sheet::ideal(common::reference(name)),
            geometries,
            instrument,
        );
        for seed in 0..*seeds {
            let (obs, _) = draw(&t, instrument, 100_000 * (k as u64 + 1) + seed);
            let result = fit(&obs, &FitOptions::default()).expect("valid");
            fits += 1;
            flagged += usize::from(result.lack_of_fit);
            chi2_flags += usize::from(
                result
                    .gof_p
                    .is_some_and(|p| p < host::analysis::gof::GOF_ALPHA),
            );
            structure_flags += usize::from(
                result
                    .structure
                    .is_some_and(|s| s.p_value < host::analysis::gof::STRUCTURE_ALPHA),
            );
        }
    }
    let rate = flagged as f64 / fits as f64;
    println!(
        "lack-of-fit on ideal data: {flagged}/{fits} = {:.2} % (χ² {chi2_flags}, structure {structure_flags})",
        100.0 * rate
    );
    assert!(fits >= 500);
    assert!(rate <= 0.02, "false-flag rate {rate}");
}

/// The paper's model alone, whatever the default: what the tests of its intervals and
/// budget measure. With the extensions the intervals also cover every member the data
/// cannot exclude, and on exact TSL they cover more than 98 % (docs/ACCURACY.md,
/// "The extensions, measured"; `extension.rs` tests that path).
fn paper_model() -> FitOptions {
    FitOptions {
        extensions: false,
        ..FitOptions::default()
    }
}

/// Coverage share of each of σ, ρs, ρd over `seeds` fits of `name` on the full grid, the
/// paper's model alone.
fn coverage(
    name: &str,
    instrument: &Instrument,
    seeds: u64,
    base: u64,
    with_shared: bool,
) -> [f64; 3] {
    let t = truth(
        &Sheet::ideal(common::reference(name)),
        &common::full_grid(),
        instrument,
    );
    let p = common::reference(name).to_array();
    let mut covered = [0usize; 3];
    for seed in 0..seeds {
        let (obs, shared) = draw(&t, instrument, base + seed);
        let shared = if with_shared { shared } else { Vec::new() };
        let result = fit::fit_with_shared(&obs, &shared, &paper_model()).expect("valid");
        for i in 0..3 {
            covered[i] += usize::from(covers(result.ci95[i], p[i]));
        }
    }
    covered.map(|c| c as f64 / seeds as f64)
}

/// On ideal data the 95 % intervals of σ, ρs, ρd cover the truth in 90–98 % of 300 fits
/// (G: η fitted; PPC: η at its bound 3).
#[test]
fn intervals_cover_the_truth_on_ideal_data() {
    for name in ["G", "PPC"] {
        let share = coverage(name, &Instrument::issue(), 300, 200_000, false);
        println!(
            "{name}: coverage σ {:.3} ρs {:.3} ρd {:.3} over 300 fits",
            share[0], share[1], share[2]
        );
        for (i, s) in share.iter().enumerate() {
            assert!(
                (0.90..=0.98).contains(s),
                "{name} parameter {i}: coverage {s}"
            );
        }
    }
}

/// Errors shared by readings (the white reading at each θi, 0.5 %; the tile certificate,
/// 1 %), drawn in the data: passed to the fit as `SharedError`s the intervals still cover in
/// 90–98 % of 300 fits; treated as independent (today's fit) they do not.
#[test]
fn shared_errors_keep_the_coverage_and_ignoring_them_loses_it() {
    let instrument = Instrument {
        white_rel: 0.005,
        tile_rel: 0.01,
        ..Instrument::issue()
    };
    let with = coverage("G", &instrument, 300, 300_000, true);
    let without = coverage("G", &instrument, 300, 300_000, false);
    println!(
        "G with shared errors: coverage σ {:.3} ρs {:.3} ρd {:.3}; treated as independent: σ {:.3} ρs {:.3} ρd {:.3}",
        with[0], with[1], with[2], without[0], without[1], without[2]
    );
    for (i, s) in with.iter().enumerate() {
        assert!(
            (0.90..=0.98).contains(s),
            "parameter {i}: coverage {s} with the shared errors"
        );
    }
    assert!(
        without[2] < 0.5,
        "ρd's coverage without the shared errors: {}",
        without[2]
    );
}

/// The budget: one term per shared error plus the reading noise, adding up to the
/// covariance's diagonal; the tile's 1 % dominates ρd.
#[test]
fn the_budget_adds_up_to_the_covariance() {
    let instrument = Instrument {
        white_rel: 0.005,
        tile_rel: 0.01,
        ..Instrument::issue()
    };
    let t = truth(
        &Sheet::ideal(common::reference("G")),
        &common::full_grid(),
        &instrument,
    );
    let (obs, shared) = draw(&t, &instrument, 7);
    let result = fit::fit_with_shared(&obs, &shared, &paper_model()).expect("valid");
    let names: Vec<&str> = result.budget.iter().map(|b| b.name.as_str()).collect();
    assert_eq!(
        names,
        [
            "reading noise",
            "white θi = 20°",
            "white θi = 30°",
            "white θi = 45°",
            "white θi = 60°",
            "tile certificate"
        ]
    );
    for i in 0..3 {
        let sum: f64 = result.budget.iter().map(|b| b.variance[i]).sum();
        assert!(
            (sum - result.covariance[i][i]).abs() <= 1e-9 * result.covariance[i][i],
            "parameter {i}: {sum} vs {}",
            result.covariance[i][i]
        );
    }
    let tile = &result.budget[5];
    assert!(
        tile.variance[model::RHO_D] > 0.5 * result.covariance[model::RHO_D][model::RHO_D],
        "{:?}",
        result.budget
    );
    // ρd moves with the tile: 1 % of it.
    assert!((tile.variance[model::RHO_D].sqrt() / result.params.rho_d - 0.01).abs() < 0.001);
}

#[test]
fn shared_errors_are_validated() {
    let obs: Vec<Observation> = valid()
        .into_iter()
        .map(|o| Observation {
            std: Some(0.01),
            ..o
        })
        .collect();
    let opts = FitOptions::default();
    let short = fit::SharedError {
        name: "tile certificate".into(),
        sensitivity: vec![0.01; obs.len() - 1],
        additive: Vec::new(),
    };
    let e = fit::fit_with_shared(&obs, &[short], &opts).unwrap_err();
    assert!(
        matches!(
            e,
            FitError::SharedErrorLength {
                found: 11,
                expected: 12,
                ..
            }
        ),
        "{e}"
    );
    assert!(e.to_string().contains("tile certificate"), "{e}");
    let mut sensitivity = vec![0.01; obs.len()];
    sensitivity[4] = f64::NAN;
    let e = fit::fit_with_shared(
        &obs,
        &[fit::SharedError {
            name: "white θi = 20°".into(),
            sensitivity,
            additive: Vec::new(),
        }],
        &opts,
    )
    .unwrap_err();
    assert!(
        matches!(e, FitError::SharedErrorValue { index: 4, .. }),
        "{e}"
    );
    assert_eq!(e.reading_index(), Some(4));
    let unweighted = valid();
    let e = fit::fit_with_shared(
        &unweighted,
        &[fit::SharedError {
            name: "lamp drift".into(),
            sensitivity: vec![0.01; 12],
            additive: Vec::new(),
        }],
        &opts,
    )
    .unwrap_err();
    assert!(
        matches!(e, FitError::SharedErrorWithoutUncertainties { .. }),
        "{e}"
    );
}

/// The analysis of a table of `obs` (the lines a file would give them), as `gonio fit` makes it.
fn analysed(obs: &[Observation]) -> result::Report {
    let lines: Vec<usize> = (2..2 + obs.len()).collect();
    let readings = result::Readings {
        source: "eta.csv",
        sample: "eta-1",
        observations: obs,
        lines: &lines,
    };
    result::analyse(&readings, &FitOptions::default(), None).expect("valid")
}

/// The issue's scene σ = 10°, ρs = 5, η = 1.001 (F ∝ η² − 1 ≈ 0.002): only ρs·(η²−1) is
/// determined. ρs is null with its reason, the class is not decided from it (flag
/// `not-identified`), and the nearest reference does not use it. Today: ρs 4924, SG 100 %.
#[test]
fn an_undetermined_rho_s_is_null_and_never_used() {
    let p = Params {
        sigma_deg: 10.0,
        rho_s: 5.0,
        rho_d: 0.5,
        eta: 1.001,
    };
    for (label, geometries) in [
        ("full grid", common::full_grid()),
        ("M = 12", common::strategy1_m12()),
        ("strategy 2, δ = 3°", common::strategy2(3)),
    ] {
        let instrument = Instrument::issue();
        let t = truth(&Sheet::ideal(p), &geometries, &instrument);
        for seed in 0..4 {
            let (obs, _) = draw(&t, &instrument, 400 + seed);
            let result = fit(&obs, &FitOptions::default()).expect("valid");
            assert_eq!(
                result.reported(model::RHO_S),
                None,
                "{label} seed {seed}: ρs {} reported",
                result.params.rho_s
            );
            assert!(
                result.ci95[model::RHO_S].is_none() && result.std_error(model::RHO_S).is_none()
            );
            assert_eq!(result.covariance[model::RHO_S], [0.0; 4]);
            assert!(
                result.not_identified().iter().any(|u| u.param == "rho_s"),
                "{label}: no reason given"
            );
            let c = classify(&result);
            assert_eq!(
                c.class, None,
                "{label} seed {seed}: class {:?} from an undetermined ρs",
                c.class
            );
            // The nearest reference does not move with the undetermined value.
            let mut other = result.clone();
            other.params.rho_s *= 1e-3;
            assert_eq!(
                host::analysis::classify::nearest_reference(&other),
                (c.nearest_reference, c.nearest_distance)
            );
            let r = analysed(&obs);
            assert!(r.flags.contains(&Flag::NotIdentified), "{:?}", r.flags);
            let json = result::to_json(&r);
            assert!(
                json["rho_s"].is_null() && json["class"].is_null() && json["ok"] == false,
                "{json}"
            );
            assert!(
                json["not_identified"]
                    .as_array()
                    .is_some_and(|a| a.iter().any(|u| u["param"] == "rho_s")),
                "{json}"
            );
        }
    }
}

/// η held at its lower bound 1: ρs = A/(η²−1) is unbounded above there, but the readings
/// bound η from above, and the note gives ρs's lower limit, its value at η's profiled 95 %
/// upper limit. On sheets whose η is within a few of its standard errors of 1 the limit is
/// below the true ρs in at least 95 % of the fits that hold η at 1, a semi-gloss gets its
/// class from it (σ far below the limit), and a sheet whose ρs is below its σ (rough by
/// the tree) never reads as glossy. (Where η is about two standard errors above 1, the few
/// fits that reach 1 are those whose η came out low, and their limit is above the truth:
/// docs/ACCURACY.md, "η held at 1".)
#[test]
fn a_rho_s_known_only_from_below_at_eta_one_is_below_the_truth_and_decides_glossy() {
    // SG's amplitude ρs·(η²−1) = 57.1·(1.02²−1) with η at 1.001; and the sheet of the test
    // above (σ 10°, ρs 5, η 1.001), rough by σ > ρs.
    let semi_gloss = Params {
        sigma_deg: 1.9,
        rho_s: 57.1 * (1.02f64.powi(2) - 1.0) / (1.001f64.powi(2) - 1.0),
        rho_d: 0.795,
        eta: 1.001,
    };
    let rough = Params {
        sigma_deg: 10.0,
        rho_s: 5.0,
        rho_d: 0.5,
        eta: 1.001,
    };
    for (label, p, geometries, glossy) in [
        (
            "semi-gloss, strategy 2 δ = 1°",
            semi_gloss,
            common::strategy2(1),
            true,
        ),
        ("σ above ρs, full grid", rough, common::full_grid(), false),
    ] {
        let instrument = Instrument::issue();
        let t = truth(&Sheet::ideal(p), &geometries, &instrument);
        let (mut at_floor, mut below_truth, mut glossy_fits) = (0usize, 0usize, 0usize);
        for seed in 0..120 {
            let (obs, _) = draw(&t, &instrument, 7_100 + seed);
            let result = fit(&obs, &FitOptions::default()).expect("valid");
            let Some(lower) = result.notes.iter().find_map(|n| match n {
                Note::EtaAtBound { eta, rho_s_lower } if *eta == 1.0 => Some(*rho_s_lower),
                _ => None,
            }) else {
                continue;
            };
            at_floor += 1;
            let lower = lower.expect("a lower limit with η held at 1");
            assert!(
                lower.is_finite() && lower > 0.0,
                "{label} seed {seed}: {lower}"
            );
            below_truth += usize::from(lower <= p.rho_s);
            let c = classify(&result);
            if glossy {
                assert_eq!(
                    c.class,
                    Some(Class::SG),
                    "{label} seed {seed}: ρs ≥ {lower}"
                );
            }
            // A class from a limit at a bound is a best guess, and ρs stays not identified.
            assert!(
                c.confidence <= host::analysis::classify::LACK_OF_FIT_CONFIDENCE_CAP,
                "{label} seed {seed}: confidence {}",
                c.confidence
            );
            let r = analysed(&obs);
            let json = result::to_json(&r);
            assert!(
                r.flags.contains(&Flag::NotIdentified)
                    && json["rho_s"].is_null()
                    && json["rho_s_lower"].as_f64() == Some(lower),
                "{label} seed {seed}: {json}"
            );
            glossy_fits += usize::from(c.group == Some(host::analysis::classify::Group::Glossy));
        }
        println!(
            "{label}: η held at 1 in {at_floor} of 120 fits; ρs's lower limit below the truth {:.0} in {below_truth}; glossy in {glossy_fits}",
            p.rho_s
        );
        assert!(at_floor >= 15, "{label}: η at 1 in only {at_floor} fits");
        assert!(
            below_truth as f64 >= 0.95 * at_floor as f64,
            "{label}: the lower limit above the truth in {} of {at_floor}",
            at_floor - below_truth
        );
        assert_eq!(glossy_fits, if glossy { at_floor } else { 0 }, "{label}");
    }
}

/// Without `std` the noise is estimated from the residuals and the result says so: a note,
/// the field, no χ² p-value, the structure check still made.
#[test]
fn unweighted_csv_says_its_noise_came_from_the_residuals() {
    let obs = common::noisy(&common::reference("PPC"), &common::full_grid(), 11);
    let mut text = String::from("theta_i,theta_r,radiance_factor\n");
    for o in &obs {
        text += &format!(
            "{},{},{}\n",
            o.theta_i_deg, o.theta_r_deg, o.radiance_factor
        );
    }
    let sets = host::output::dataset::parse_csv(&text, "ppc").expect("valid CSV");
    let readings = result::Readings {
        source: "ppc.csv",
        sample: &sets[0].sample,
        observations: &sets[0].observations,
        lines: &sets[0].lines,
    };
    let r = result::analyse(&readings, &FitOptions::default(), None).expect("valid");
    let f = &r.fit;
    assert!(!f.weighted);
    let std = f.noise_from_residuals.expect("the noise estimate");
    assert!(
        f.notes
            .iter()
            .any(|n| matches!(n, Note::NoiseFromResiduals { .. })),
        "{:?}",
        f.notes
    );
    assert!(f.chi2.is_none() && f.gof_p.is_none());
    assert!(
        f.structure.is_some(),
        "the structure check runs without uncertainties"
    );
    let json = result::to_json(&r);
    assert!(json["gof_p"].is_null() && json["chi2"].is_null(), "{json}");
    assert_eq!(json["noise_from_residuals"].as_f64(), Some(std));
    assert!(
        json["dof"].as_u64().is_some() && json["flags"].is_array() && json["ok"].is_boolean(),
        "{json}"
    );
    assert!(
        json["notes"]
            .as_array()
            .is_some_and(|n| n.iter().any(|v| v["kind"] == "noise_from_residuals")),
        "{json}"
    );
    let table = result::to_table(&r);
    assert!(table.contains("estimated from the residuals"), "{table}");
    // The weighted fit of the same readings reports χ² and its p-value instead.
    let weighted = common::synthetic(
        &common::reference("PPC"),
        &common::full_grid(),
        1.0,
        0.01,
        0.003,
        11,
        true,
    );
    let w = fit(&weighted, &FitOptions::default()).expect("valid");
    assert!(w.chi2.is_some() && w.gof_p.is_some() && w.noise_from_residuals.is_none());
}

/// `gonio fit --json` carries chi2, dof, gof_p, flags and ok, and exits 3 (flagged) when
/// a data set is flagged and none failed; 0 when all are clean.
#[test]
fn gonio_fit_reports_the_goodness_of_fit_and_exits_3_when_flagged() {
    let dir = std::env::temp_dir().join(format!("gonio-fit-gof-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let write = |name: &str, obs: &[Observation]| {
        let mut text = String::from("theta_i,theta_r,radiance_factor,std\n");
        for o in obs {
            text += &format!(
                "{},{},{},{}\n",
                o.theta_i_deg,
                o.theta_r_deg,
                o.radiance_factor,
                o.std.expect("weighted")
            );
        }
        let path = dir.join(name);
        std::fs::write(&path, text).expect("write");
        path
    };
    let instrument = Instrument::issue();
    let ggx = truth(
        &Sheet {
            params: common::reference("G"),
            lobe: Lobe::Ggx,
            bump: None,
        },
        &common::strategy2(2),
        &instrument,
    );
    let ideal = truth(
        &Sheet::ideal(common::reference("PPC")),
        &common::strategy2(2),
        &instrument,
    );
    // A GGX lobe alone is now named (a heavy-tailed lobe); with a 5 % ripple along θr on
    // top, no term of the fit's family describes the table.
    let mut rippled = draw(&ggx, &instrument, 1).0;
    for o in &mut rippled {
        o.radiance_factor *= 1.0 + 0.05 * (o.theta_r_deg * std::f64::consts::PI / 6.0).sin();
    }
    let flagged = write("ggx.csv", &rippled);
    let clean = write("ppc.csv", &draw(&ideal, &instrument, 1).0);
    let run = |files: &[&std::path::Path]| {
        std::process::Command::new(env!("CARGO_BIN_EXE_gonio"))
            .args(["fit", "--json"])
            .args(files)
            .output()
            .expect("run gonio")
    };
    let out = run(&[&clean]);
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let out = run(&[&clean, &flagged]);
    assert_eq!(
        out.status.code(),
        Some(3),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let lines: Vec<serde_json::Value> = String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).expect("JSON"))
        .collect();
    for line in &lines {
        for key in [
            "chi2",
            "dof",
            "gof_p",
            "flags",
            "ok",
            "structure",
            "budget",
            "not_identified",
        ] {
            assert!(line.get(key).is_some(), "missing {key}: {line}");
        }
    }
    assert_eq!(lines[0]["ok"], true);
    assert_eq!(lines[1]["ok"], false);
    assert!(
        lines[1]["flags"]
            .as_array()
            .is_some_and(|f| f.contains(&serde_json::json!("lack-of-fit"))),
        "{}",
        lines[1]
    );
    assert!(
        lines[1]["gof_p"].as_f64().is_some_and(|p| p < 1e-6),
        "{}",
        lines[1]
    );
    assert!(
        lines[1]["class_confidence"]
            .as_f64()
            .is_none_or(|c| c < 0.95)
    );
    // A failed file still wins: exit 1.
    let broken = dir.join("broken.csv");
    std::fs::write(&broken, "theta_i,theta_r,radiance_factor\n20,0,nope\n").expect("write");
    assert_eq!(run(&[&flagged, &broken]).status.code(), Some(1));
    // The table shows the fit's verdict.
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_gonio"))
        .arg("fit")
        .arg(&flagged)
        .output()
        .expect("run gonio");
    let table = String::from_utf8_lossy(&out.stdout);
    assert!(
        table.contains("LACK OF FIT")
            && table.contains("flags: lack-of-fit")
            && table.contains("χ²"),
        "{table}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// Bins of a sweep across glossy paper's peak, each the detector's reading averaged over
/// its 1.2° of travel (dense quadrature, not the fit's own nodes), with 0.1 % noise drawn
/// per seed: fitted as bins, σ is recovered within its interval; fitted as if each bin had
/// been read standing at its middle, σ comes out biased wide by far more than its
/// interval. So the bins' travel is modelled where it matters.
#[test]
fn bins_read_while_moving_are_fitted_as_such() {
    use rand::{Rng, SeedableRng};
    let truth = Params {
        sigma_deg: 0.8,
        rho_s: 57.8,
        rho_d: 0.855,
        eta: 1.19,
    };
    let span = 1.2;
    let dense = |ti: f64, tr: f64| {
        let n = 600;
        (0..n)
            .map(|k| {
                model::observed_radiance_factor(
                    &truth,
                    ti,
                    tr - 0.5 * span + (k as f64 + 0.5) * span / n as f64,
                    1.0,
                )
            })
            .sum::<f64>()
            / n as f64
    };
    // Seed 7 and nineteen drawn each run. The interval misses the truth (5 %) and the
    // lack-of-fit flag fires on the model's own data (its false-alarm rate) at stated
    // rates, so both are counted against binomial bounds over the twenty, not asserted per
    // seed; P(≥ 5 misses of 20 at 5 %) is 0.3 %.
    let mut seeds = vec![7u64];
    seeds.extend((0..19).map(|_| rand::rng().random::<u64>()));
    let (mut misses, mut flagged) = (Vec::new(), Vec::new());
    for seed in seeds {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let mut bins = Vec::new();
        for ti in [20.0, 30.0, 45.0, 60.0] {
            let mut tr = ti - 8.0;
            while tr <= ti + 8.0 {
                let f = dense(ti, tr);
                let std = 1e-3 * f + 1e-4;
                let noise: f64 = rng.sample(rand_distr::StandardNormal);
                bins.push(Observation {
                    theta_i_deg: ti,
                    theta_r_deg: tr,
                    radiance_factor: f + std * noise,
                    std: Some(std),
                    theta_r_span_deg: span,
                });
                tr += span;
            }
        }
        let as_bins = fit(&bins, &FitOptions::default()).expect("fit");
        let (lo, hi) = as_bins.ci95[0].expect("σ's interval");
        if !(lo <= truth.sigma_deg && truth.sigma_deg <= hi) {
            misses.push((seed, as_bins.sigma_deg(), lo, hi));
        }
        if as_bins.lack_of_fit {
            flagged.push(seed);
        }
        let still: Vec<Observation> = bins
            .iter()
            .map(|o| Observation {
                theta_r_span_deg: 0.0,
                ..*o
            })
            .collect();
        let as_still = fit(&still, &FitOptions::default()).expect("fit");
        let bias = as_still.sigma_deg().expect("σ") / truth.sigma_deg - 1.0;
        let half_width = 0.5 * (hi - lo) / truth.sigma_deg;
        assert!(
            bias > 5.0 * half_width,
            "seed {seed}: ignoring the travel biases σ by {:.2} %, its interval ±{:.2} %",
            100.0 * bias,
            100.0 * half_width
        );
    }
    assert!(
        misses.len() <= 4,
        "σ's interval missed the truth in {} of 20 (at most 4): {misses:?}",
        misses.len()
    );
    assert!(
        flagged.len() <= 2,
        "bins fitted as bins are the model, yet lack-of-fit for seeds {flagged:?} of 20"
    );
}
