//! The gain calibration and the budget in whole simulated sessions: the simulator draws
//! each range-gain ratio off its nominal value (`--gain-error`), the tile off its
//! certificate (`--tile-error`) and a lamp drift; the session calibrates the ratios its
//! readings use on the sample and carries every shared error into the fit.
use host::analysis::budget::{self, BudgetReading};
use host::analysis::classify::REFERENCES;
use host::analysis::fit::{FitOptions, Observation, fit};
use host::analysis::model::{self, Params};
use host::instrument::calibration::Calibration;
use host::instrument::sim::SimOptions;
use host::session::gains;
use host::session::{Outcome, Policy};
use host::study::{SimulatedRun, simulated_session};

/// A whole session of `sample` on the simulator `options` make, and the instrument's truth.
fn run(sample: &str, options: &SimOptions, policy: Policy) -> (Outcome, hil_sim::Truth) {
    simulated_session(
        &SimulatedRun {
            sample,
            options,
            policy,
            integration_ms: None,
        },
        |session| session,
    )
    .expect("a session")
}

fn reference(name: &str) -> Params {
    REFERENCES
        .iter()
        .find(|r| r.name == name)
        .expect("a Table 6 paper")
        .params
}

fn with_gain_error(seed: u64, pct: f64) -> SimOptions {
    SimOptions {
        seed,
        gain_error: Some(pct),
        ..SimOptions::default()
    }
}

/// The session's readings converted again with `calibration`, one per geometry.
fn observations(outcome: &Outcome, calibration: &Calibration) -> Vec<Observation> {
    let mut seen = std::collections::BTreeSet::new();
    outcome
        .points
        .iter()
        .filter(|p| seen.insert(((p.theta_i_deg * 1e4) as i64, (p.theta_r_deg * 1e4) as i64)))
        .filter_map(|p| {
            let (radiance_factor, std) = calibration
                .radiance_factor(p.theta_i_deg, &p.reading)
                .ok()?;
            Some(Observation {
                theta_i_deg: p.theta_i_deg,
                theta_r_deg: p.theta_r_deg,
                radiance_factor,
                std: Some(std),
                theta_r_span_deg: 0.0,
            })
        })
        .collect()
}

#[test]
fn the_ratios_the_readings_use_are_calibrated_and_agree_with_the_instrument() {
    let (mut within, mut ratios, mut worst) = (0, 0, 0.0f64);
    let (mut nominal_sq, mut calibrated_sq) = (0.0, 0.0);
    let mut seconds = Vec::new();
    for (sample, seeds) in [("G", 0..8u64), ("SG", 100..108), ("J1", 200..202)] {
        for seed in seeds {
            let (outcome, truth) = run(sample, &with_gain_error(seed, 2.0), Policy::Paper);
            let c = &outcome.calibration;
            // Every pair a reading uses is calibrated, and no other.
            let mut nominal = c.clone();
            nominal.gain_ratios.clear();
            let used = gains::pairs_needed(
                &nominal,
                outcome.points.iter().map(|p| (p.theta_i_deg, &p.reading)),
            );
            let calibrated: Vec<u8> = c.gain_ratios.iter().map(|g| g.lower_range).collect();
            assert_eq!(calibrated, used, "{sample} seed {seed}");
            for g in &c.gain_ratios {
                let p = usize::from(g.lower_range);
                let true_ratio = truth.relative_gains[p + 1] / truth.relative_gains[p];
                let nominal_ratio = c.relative_gains[p + 1] / c.relative_gains[p];
                let (lower, upper) = (
                    c.net_counts(&g.on_lower).unwrap(),
                    c.net_counts(&g.on_upper).unwrap(),
                );
                let u = g.relative_uncertainty.hypot(gains::dark_relative(
                    c,
                    g.lower_range,
                    lower,
                    upper,
                ));
                let z = (g.ratio / true_ratio - 1.0) / u;
                ratios += 1;
                within += usize::from(z.abs() <= 1.96);
                worst = worst.max(z.abs());
                nominal_sq += (nominal_ratio / true_ratio - 1.0).powi(2);
                calibrated_sq += (g.ratio / true_ratio - 1.0).powi(2);
                seconds.push(g.device_seconds);
                println!(
                    "{sample} seed {seed}: ratio {}/{} {:.5} true {:.5} ± {:.3} % (own {:.3} %) z {z:+.2}, {:.2} device s at ({}, {})",
                    p,
                    p + 1,
                    g.ratio,
                    true_ratio,
                    100.0 * u,
                    100.0 * g.relative_uncertainty,
                    g.device_seconds,
                    g.theta_i_deg,
                    g.theta_r_deg
                );
            }
        }
    }
    let rms = |sq: f64| (sq / ratios as f64).sqrt();
    seconds.sort_by(f64::total_cmp);
    println!(
        "{within}/{ratios} within 1.96 u, worst |z| {worst:.2}; error RMS nominal {:.3} % → calibrated {:.3} %; device s per ratio median {:.2}, max {:.2}",
        100.0 * rms(nominal_sq),
        100.0 * rms(calibrated_sq),
        seconds[seconds.len() / 2],
        seconds[seconds.len() - 1]
    );
    assert!(
        ratios >= 24,
        "glossy papers use range 1 and G range 2: {ratios} ratios"
    );
    assert!(within as f64 >= 0.85 * ratios as f64, "{within}/{ratios}");
    assert!(worst < 4.5, "{worst}");
    assert!(
        rms(calibrated_sq) < 0.25 * rms(nominal_sq),
        "the calibration removes most of the gain error"
    );
}

#[test]
fn a_gain_error_no_longer_biases_sg() {
    // Issue 12: a 1–2 % gain error moved SG's ρs by 17 %. The same sessions' readings
    // converted with the nominal gains and fitted as before (no shared errors), against the
    // session's own result: calibrated gains, every shared error in the fit.
    let truth = reference("SG");
    let options = FitOptions {
        acceptance_deg: Some(model::DEFAULT_ACCEPTANCE_DEG),
        ..FitOptions::default()
    };
    let (mut nominal, mut session, mut z) = (Vec::new(), Vec::new(), Vec::new());
    let (mut covered_before, mut covered) = (0, 0);
    for seed in 300..320u64 {
        let (outcome, _) = run("SG", &with_gain_error(seed, 2.0), Policy::Paper);
        let mut without = outcome.calibration.clone();
        without.gain_ratios.clear();
        let before = fit(&observations(&outcome, &without), &options).expect("a fit");
        let after = &outcome.report.fit;
        nominal.push((before.params.rho_s / truth.rho_s - 1.0).abs());
        session.push((after.params.rho_s / truth.rho_s - 1.0).abs());
        z.push(
            (after.params.rho_s - truth.rho_s)
                / after.covariance[model::RHO_S][model::RHO_S].sqrt(),
        );
        covered_before += usize::from(covers(&before, model::RHO_S, truth.rho_s));
        covered += usize::from(covers(after, model::RHO_S, truth.rho_s));
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let (n, c) = (median(&mut nominal), median(&mut session));
    let mean_z = z.iter().sum::<f64>() / z.len() as f64;
    println!(
        "SG ρs, 2 % gain errors: |error| median {:.2} % (worst {:.2} %) with nominal gains, {:.2} % (worst {:.2} %) calibrated; covered {covered_before}/20 → {covered}/20; mean z {mean_z:+.2}",
        100.0 * n,
        100.0 * nominal[nominal.len() - 1],
        100.0 * c,
        100.0 * session[session.len() - 1]
    );
    assert!(c < 0.5 * n, "calibrated {c} vs nominal {n}");
    // What error remains is the fit's own, and its interval says so.
    assert!(covered >= 17, "{covered}/20");
    assert!(mean_z.abs() < 0.5, "{mean_z}");
}

fn covers(f: &host::analysis::fit::FitResult, index: usize, truth: f64) -> bool {
    f.ci95[index].is_some_and(|(lo, hi)| lo <= truth && truth <= hi)
}

/// Coverage of σ, ρs, ρd by the session's own intervals over `seeds` sessions of `paper`
/// with `options(seed)`; sessions whose fit left a parameter undetermined count as misses.
fn session_coverage(
    paper: &str,
    seeds: std::ops::Range<u64>,
    options: impl Fn(u64) -> SimOptions,
) -> ([usize; 3], usize) {
    let truth = reference(paper);
    let mut covered = [0; 3];
    let mut n = 0;
    for seed in seeds {
        let (outcome, _) = run(paper, &options(seed), Policy::Paper);
        let f = &outcome.report.fit;
        n += 1;
        for (k, (i, t)) in [
            (model::SIGMA, truth.sigma_deg),
            (model::RHO_S, truth.rho_s),
            (model::RHO_D, truth.rho_d),
        ]
        .into_iter()
        .enumerate()
        {
            covered[k] += usize::from(covers(f, i, t));
        }
    }
    (covered, n)
}

#[test]
fn with_gain_and_tile_errors_the_sessions_intervals_cover() {
    // The simulator draws each gain ratio off by 2 % and the tile off its certificate by
    // 0.5 % (its sd), the lamp drifts 0.2 %/h; the session calibrates the gains it uses and
    // carries every shared error.
    let options = |seed: u64| SimOptions {
        seed,
        gain_error: Some(2.0),
        tile_error: Some(0.5),
        ..SimOptions::default()
    };
    for paper in ["SG", "G", "PPC", "J1"] {
        let ([sigma, rho_s, rho_d], n) = session_coverage(paper, 500..520, options);
        println!("{paper}: covered σ {sigma}/{n}, ρs {rho_s}/{n}, ρd {rho_d}/{n}");
        for (what, c) in [("ρs", rho_s), ("ρd", rho_d)] {
            // 20 sessions: at least 17 (85 %; 95 % coverage gives fewer in 1.6 % of runs);
            // the campaign (below) is the 90–98 % claim.
            assert!(c >= 17, "{paper} {what}: {c}/{n}");
        }
    }
}

/// Today's treatment of the same readings: nominal gains, and the white's and dark's
/// errors folded into each reading's own as if independent (the tile, gains and drift
/// left out).
fn as_today(outcome: &Outcome) -> Option<host::analysis::fit::FitResult> {
    let mut nominal = outcome.calibration.clone();
    nominal.gain_ratios.clear();
    let observations = observations(outcome, &nominal);
    let readings: Vec<BudgetReading> = {
        let mut seen = std::collections::BTreeSet::new();
        outcome
            .points
            .iter()
            .filter(|p| seen.insert(((p.theta_i_deg * 1e4) as i64, (p.theta_r_deg * 1e4) as i64)))
            .filter(|p| nominal.radiance_factor(p.theta_i_deg, &p.reading).is_ok())
            .map(|p| BudgetReading {
                theta_i_deg: p.theta_i_deg,
                reading: p.reading,
                age_s: 0.0,
            })
            .collect()
    };
    let shared = budget::shared_errors(&nominal, &readings).ok()?;
    let folded: Vec<Observation> = observations
        .iter()
        .enumerate()
        .map(|(k, o)| {
            let extra: f64 = shared
                .iter()
                .filter(|t| {
                    matches!(
                        budget::TermKind::of(&t.name),
                        budget::TermKind::White | budget::TermKind::Dark
                    )
                })
                .map(|t| t.total(k).powi(2))
                .sum();
            Observation {
                std: o.std.map(|u| (u * u + extra).sqrt()),
                ..*o
            }
        })
        .collect();
    let options = FitOptions {
        acceptance_deg: Some(model::DEFAULT_ACCEPTANCE_DEG),
        ..FitOptions::default()
    };
    fit(&folded, &options).ok()
}

/// The campaign: 200 sessions per paper with the simulator's gain (1 %, `--physics real`'s)
/// and tile (0.5 %) errors and lamp drift; the session's intervals against today's
/// treatment of the same readings. Release build:
/// `cargo test --release -p host --test it budget_session -- --ignored --nocapture`.
#[test]
#[ignore = "a campaign of 800 sessions: run in release"]
fn campaign_coverage_with_gain_and_tile_errors() {
    let options = |seed: u64| SimOptions {
        seed,
        gain_error: Some(1.0),
        tile_error: Some(0.5),
        ..SimOptions::default()
    };
    for paper in ["G", "SG", "PPC", "J1"] {
        let truth = reference(paper);
        let targets = [
            (model::SIGMA, truth.sigma_deg),
            (model::RHO_S, truth.rho_s),
            (model::RHO_D, truth.rho_d),
        ];
        let (mut now, mut today, mut n) = ([0usize; 3], [0usize; 3], 0usize);
        let (mut gain_seconds, mut measuring_seconds) = (0.0, 0.0);
        for seed in 1_000..1_200u64 {
            let (outcome, _) = run(paper, &options(seed), Policy::Paper);
            n += 1;
            gain_seconds += outcome
                .calibration
                .gain_ratios
                .iter()
                .map(|g| g.device_seconds)
                .sum::<f64>();
            measuring_seconds += outcome.device_seconds;
            let before = as_today(&outcome);
            for (k, &(i, t)) in targets.iter().enumerate() {
                now[k] += usize::from(covers(&outcome.report.fit, i, t));
                today[k] += usize::from(before.as_ref().is_some_and(|f| covers(f, i, t)));
            }
        }
        println!(
            "{paper}: {n} sessions; covered σ {}/{n} (today {}), ρs {}/{n} (today {}), ρd {}/{n} (today {}); gain calibration {:.2} of {:.1} device s measuring per session",
            now[0],
            today[0],
            now[1],
            today[1],
            now[2],
            today[2],
            gain_seconds / n as f64,
            measuring_seconds / n as f64
        );
        for (k, what) in [(1, "ρs"), (2, "ρd")] {
            let rate = now[k] as f64 / n as f64;
            assert!(
                (0.90..=0.98).contains(&rate),
                "{paper} {what}: {}/{n}",
                now[k]
            );
        }
    }
}

/// The readings of a session (one per geometry) as the budget and the fit take them.
fn budget_inputs(outcome: &Outcome) -> (Vec<BudgetReading>, Vec<Observation>) {
    let c = &outcome.calibration;
    let mut seen = std::collections::BTreeSet::new();
    outcome
        .points
        .iter()
        .filter(|p| seen.insert(((p.theta_i_deg * 1e4) as i64, (p.theta_r_deg * 1e4) as i64)))
        .filter_map(|p| {
            let (radiance_factor, std) = c.radiance_factor(p.theta_i_deg, &p.reading).ok()?;
            Some((
                BudgetReading {
                    theta_i_deg: p.theta_i_deg,
                    reading: p.reading,
                    age_s: 0.0,
                },
                Observation {
                    theta_i_deg: p.theta_i_deg,
                    theta_r_deg: p.theta_r_deg,
                    radiance_factor,
                    std: Some(std),
                    theta_r_span_deg: 0.0,
                },
            ))
        })
        .unzip()
}

/// The model's values under `f` at the observations (its window and arm offset included).
fn model_values(f: &host::analysis::fit::FitResult, observations: &[Observation]) -> Vec<f64> {
    let offset = f.arm_offset.map_or(0.0, |a| a.deg);
    let a = f.acceptance_deg.unwrap_or(0.0);
    observations
        .iter()
        .map(|o| {
            model::observed_radiance_factor(&f.params, o.theta_i_deg, o.theta_r_deg + offset, a)
        })
        .collect()
}

#[test]
fn errors_that_scale_the_readings_do_not_pull_the_fit_down() {
    // Built from the measured values, the tile's and the whites' errors let the GLS fit
    // follow the low readings (Peelle's puzzle): G's ρd came out 0.25 % low, half its
    // interval, in every session. The fit evaluates the budget's sensitivities at its model
    // (fit_with_shared); undoing that (×y/f̂ before the fit) shows what it guards against.
    let options = FitOptions {
        acceptance_deg: Some(model::DEFAULT_ACCEPTANCE_DEG),
        ..FitOptions::default()
    };
    for paper in ["G", "SG"] {
        let truth = reference(paper);
        let (mut measured, mut budgeted, mut n) = (0.0, 0.0, 0.0);
        for seed in 700..712u64 {
            let (outcome, _) = run(
                paper,
                &SimOptions {
                    seed,
                    ..SimOptions::default()
                },
                Policy::Paper,
            );
            let (readings, observations) = budget_inputs(&outcome);
            let z = |shared: &[host::analysis::fit::SharedError]| {
                let f = host::analysis::fit::fit_with_shared(&observations, shared, &options)
                    .expect("a fit");
                (f.params.rho_d - truth.rho_d) / f.covariance[model::RHO_D][model::RHO_D].sqrt()
            };
            let shared = budget::shared_errors(&outcome.calibration, &readings).unwrap();
            budgeted += z(&shared);
            let values = model_values(&fit(&observations, &options).unwrap(), &observations);
            let at_the_readings: Vec<host::analysis::fit::SharedError> = shared
                .iter()
                .map(|t| host::analysis::fit::SharedError {
                    name: t.name.clone(),
                    sensitivity: t
                        .sensitivity
                        .iter()
                        .zip(&values)
                        .zip(&observations)
                        .map(|((s, f), o)| s * o.radiance_factor / f)
                        .collect(),
                    additive: t.additive.clone(),
                })
                .collect();
            measured += z(&at_the_readings);
            n += 1.0;
        }
        let (measured, budgeted) = (measured / n, budgeted / n);
        println!(
            "{paper}: ρd's mean z over {n} sessions: covariance at the readings {measured:+.3}, at the model (the session's) {budgeted:+.3}"
        );
        assert!(budgeted.abs() < 0.15, "{paper}: {budgeted}");
        if paper == "G" {
            assert!(
                measured < -0.3,
                "the effect this guards against: {measured}"
            );
        }
    }
}
