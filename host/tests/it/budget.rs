//! The uncertainty budget on synthetic data at the level of detector counts: a calibration
//! (dark per range, white per θi, a tile off its certificate, range gains off their
//! nominal values, a drifting lamp) and sample readings, converted as the session converts
//! them, fitted with the shared errors the budget builds.
use crate::common;
use host::analysis::budget::{self, BudgetReading, SharedError};
use host::analysis::fit::{FitOptions, FitResult, Observation, fit, fit_with_shared};
use host::analysis::model::{self, Params};
use host::instrument::calibration::{Calibration, GainRatio, Tile, WhitePoint};
use host::session::gains;
use protocol::Reading;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const FULL_SCALE: f64 = 65_535.0;

fn standard_normal(rng: &mut ChaCha8Rng) -> f64 {
    let u1: f64 = 1.0 - rng.random::<f64>();
    let u2: f64 = rng.random::<f64>();
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
}

/// What the synthetic instrument gets wrong, by standard deviation.
#[derive(Clone, Copy, Debug)]
struct Errors {
    /// Each gain ratio's relative error.
    gain_sd: f64,
    /// The tile's relative error against its certificate.
    tile_sd: f64,
    /// The lamp's drift rate, per hour (its sign drawn).
    drift_per_hour: f64,
    /// Age of the calibration when the session starts, s.
    calibration_age_s: f64,
}

impl Errors {
    const REAL: Errors = Errors {
        gain_sd: 0.01,
        tile_sd: 0.005,
        drift_per_hour: 0.002,
        calibration_age_s: 0.0,
    };
}

/// The reference instrument, at counts: the white tile reads 40 % of full
/// scale at θi = 20° on range 0, read noise 0.02 % of full scale and shot noise 0.1 % at
/// 40 % for 100 ms, dark 0.3 % of full scale, 1 kHz samples.
struct Instrument {
    rng: ChaCha8Rng,
    counts_per_unit: f64,
    true_gains: [f64; 3],
    true_tile: f64,
    lamp_rate_per_s: f64,
}

impl Instrument {
    fn new(seed: u64, errors: Errors) -> Instrument {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let g1 = 0.1 * (1.0 + errors.gain_sd * standard_normal(&mut rng));
        let g2 = g1 * 0.1 * (1.0 + errors.gain_sd * standard_normal(&mut rng));
        let true_tile = 0.99 * (1.0 + errors.tile_sd * standard_normal(&mut rng));
        let sign = if rng.random::<bool>() { 1.0 } else { -1.0 };
        let counts_per_unit = 0.4 * FULL_SCALE / (0.99 * 20f64.to_radians().cos());
        Instrument {
            rng,
            counts_per_unit,
            true_gains: [1.0, g1, g2],
            true_tile,
            lamp_rate_per_s: sign * errors.drift_per_hour / 3600.0,
        }
    }

    /// A reading of a scene of radiance factor `r` at `theta_i_deg`, at time `t_s` since the
    /// calibration, on `range` or auto-ranged (the most sensitive range below 95 % of full
    /// scale).
    fn read(
        &mut self,
        r: f64,
        theta_i_deg: f64,
        t_s: f64,
        range: Option<u8>,
        integration_ms: u16,
    ) -> Reading {
        let lamp = 1.0 + self.lamp_rate_per_s * t_s;
        let base = self.counts_per_unit * r * theta_i_deg.to_radians().cos() * lamp;
        let range = range.unwrap_or_else(|| {
            (0..3u8)
                .find(|&k| base * self.true_gains[usize::from(k)] < 0.95 * FULL_SCALE)
                .unwrap_or(2)
        });
        let signal = base * self.true_gains[usize::from(range)];
        self.sample(signal, range, integration_ms)
    }

    fn sample(&mut self, signal: f64, range: u8, integration_ms: u16) -> Reading {
        let scale = (100.0 / f64::from(integration_ms)).sqrt();
        let read = 2e-4 * FULL_SCALE;
        let shot = 1e-3 * 0.4 * FULL_SCALE * (signal.max(0.0) / (0.4 * FULL_SCALE)).sqrt();
        let sd_mean = scale * read.hypot(shot);
        let samples = u32::from(integration_ms);
        let mean = 3e-3 * FULL_SCALE + signal + sd_mean * standard_normal(&mut self.rng);
        Reading {
            mean_counts: mean as f32,
            std_counts: (sd_mean * f64::from(samples).sqrt()) as f32,
            samples,
            range,
            integration_ms,
            saturated: mean > 0.98 * FULL_SCALE,
        }
    }

    /// Dark per range, then the tile at every θi, as the session takes them.
    fn calibrate(&mut self) -> Calibration {
        let dark = (0..3u8).map(|k| self.sample(0.0, k, 100)).collect();
        let tile = self.true_tile;
        let white = protocol::schedules::INCIDENCE_DEG
            .iter()
            .map(|&t| WhitePoint {
                theta_i_deg: f64::from(t),
                reading: self.read(tile, f64::from(t), 0.0, None, 100),
            })
            .collect();
        Calibration::new(
            "synthetic".into(),
            Tile::default(),
            vec![1.0, 0.1, 0.01],
            dark,
            white,
        )
    }

    /// The gain ratio of (p, p + 1) calibrated on a spot reading 70 % of range p's full
    /// scale, to 0.1 % (as `session::gains` does).
    fn calibrate_ratio(&mut self, calibration: &mut Calibration, p: u8) {
        let base = 0.7 * FULL_SCALE / self.true_gains[usize::from(p)];
        let (lo, hi) = (p, p + 1);
        let mut lower = vec![self.sample(base * self.true_gains[usize::from(lo)], lo, 100)];
        let mut upper = vec![self.sample(base * self.true_gains[usize::from(hi)], hi, 100)];
        let (_, u) = calibration
            .ratio_from_readings(&lower[0], &upper[0])
            .unwrap();
        let nets = (
            calibration.net_counts(&lower[0]).unwrap(),
            calibration.net_counts(&upper[0]).unwrap(),
        );
        let target = gains::own_noise_target(gains::dark_relative(calibration, p, nets.0, nets.1));
        if let Some(ms) = gains::second_integration_ms(u, target, 100, 10, 10_000) {
            lower.push(self.sample(base * self.true_gains[usize::from(lo)], lo, ms));
            upper.push(self.sample(base * self.true_gains[usize::from(hi)], hi, ms));
        }
        let (on_lower, on_upper) = (
            host::instrument::calibration::pool(&lower).unwrap(),
            host::instrument::calibration::pool(&upper).unwrap(),
        );
        let (ratio, relative_uncertainty) = calibration
            .ratio_from_readings(&on_lower, &on_upper)
            .unwrap();
        calibration.gain_ratios.push(GainRatio {
            lower_range: p,
            ratio,
            relative_uncertainty,
            theta_i_deg: 60.0,
            theta_r_deg: 63.0,
            scene: "synthetic".into(),
            on_lower,
            on_upper,
            device_seconds: 0.0,
        });
    }
}

/// One synthetic session: readings of `p` at `geometries`, their observations (own noise),
/// the shared errors, and the calibration.
struct Synthetic {
    observations: Vec<Observation>,
    shared: Vec<SharedError>,
}

fn session(
    p: &Params,
    geometries: &[(f64, f64)],
    seed: u64,
    errors: Errors,
    calibrate_gains: bool,
) -> Synthetic {
    let mut instrument = Instrument::new(seed, errors);
    let mut calibration = instrument.calibrate();
    let readings: Vec<BudgetReading> = geometries
        .iter()
        .enumerate()
        .map(|(k, &(ti, tr))| {
            // Half a second per geometry after the calibration's age.
            let age_s = errors.calibration_age_s + 0.5 * k as f64;
            BudgetReading {
                theta_i_deg: ti,
                reading: instrument.read(model::radiance_factor(p, ti, tr), ti, age_s, None, 100),
                age_s,
            }
        })
        .collect();
    if calibrate_gains {
        for pair in gains::pairs_needed(
            &calibration,
            readings.iter().map(|r| (r.theta_i_deg, &r.reading)),
        ) {
            instrument.calibrate_ratio(&mut calibration, pair);
        }
    }
    let observations: Vec<Observation> = geometries
        .iter()
        .zip(&readings)
        .map(|(&(ti, tr), r)| {
            let (radiance_factor, std) = calibration
                .radiance_factor(ti, &r.reading)
                .expect("convertible");
            Observation {
                theta_i_deg: ti,
                theta_r_deg: tr,
                radiance_factor,
                std: Some(std),
                theta_r_span_deg: 0.0,
            }
        })
        .collect();
    let shared = budget::shared_errors(&calibration, &readings).expect("a budget");
    Synthetic {
        observations,
        shared,
    }
}

/// The paper's model alone, whatever the default: the budget's terms are its intervals'
/// (with the extensions a `model form` term joins them, tested in `extension.rs`).
fn options() -> FitOptions {
    FitOptions {
        acceptance_deg: None,
        extensions: false,
        ..FitOptions::default()
    }
}

/// The readings as today's code carried them: the white's and dark's errors folded into
/// each reading's own, as if independent; the tile, gains and drift not at all.
fn as_independent(s: &Synthetic) -> Vec<Observation> {
    s.observations
        .iter()
        .enumerate()
        .map(|(k, o)| {
            let folded: f64 = s
                .shared
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
                std: o.std.map(|u| (u * u + folded).sqrt()),
                ..*o
            }
        })
        .collect()
}

fn covers(fit: &FitResult, index: usize, truth: f64) -> bool {
    fit.ci95[index].is_some_and(|(lo, hi)| lo <= truth && truth <= hi)
}

/// Coverage of ρs and ρd over `seeds` sessions of `paper` with shared errors treated as
/// independent (today's treatment).
fn coverage_independent(
    paper: &str,
    geometries: &[(f64, f64)],
    seeds: u64,
    errors: Errors,
) -> (usize, usize, usize) {
    let p = common::reference(paper);
    let (mut rho_s, mut rho_d, mut n) = (0, 0, 0);
    for seed in 0..seeds {
        let s = session(&p, geometries, 10_000 + seed, errors, false);
        let Ok(f) = fit(&as_independent(&s), &options()) else {
            continue;
        };
        n += 1;
        rho_s += usize::from(covers(&f, model::RHO_S, p.rho_s));
        rho_d += usize::from(covers(&f, model::RHO_D, p.rho_d));
    }
    (rho_s, rho_d, n)
}

#[test]
fn treated_as_independent_the_shared_errors_are_not_covered() {
    // Today's baseline, which the shared terms must mend: the white and tile errors shared
    // by many readings make intervals that miss far more often than 5 %.
    let (rho_s, rho_d, n) = coverage_independent(
        "SG",
        &common::strategy2(3),
        100,
        Errors {
            gain_sd: 0.0,
            drift_per_hour: 0.0,
            ..Errors::REAL
        },
    );
    println!("SG, independent: ρs covered {rho_s}/{n}, ρd {rho_d}/{n}");
    assert!(n >= 95);
    assert!((rho_d as f64) < 0.85 * n as f64, "ρd {rho_d}/{n}");
}

/// Coverage of ρs and ρd over `seeds` sessions of `paper`, the shared errors carried as such.
fn coverage_shared(
    paper: &str,
    geometries: &[(f64, f64)],
    seeds: std::ops::Range<u64>,
    errors: Errors,
) -> (usize, usize, usize) {
    let p = common::reference(paper);
    let (mut rho_s, mut rho_d, mut n) = (0, 0, 0);
    for seed in seeds {
        let s = session(&p, geometries, seed, errors, true);
        let f = fit_with_shared(&s.observations, &s.shared, &options()).expect("a fit");
        n += 1;
        rho_s += usize::from(covers(&f, model::RHO_S, p.rho_s));
        rho_d += usize::from(covers(&f, model::RHO_D, p.rho_d));
    }
    (rho_s, rho_d, n)
}

/// 95 % intervals that cover in 90–98 % of sessions.
fn assert_coverage(what: &str, covered: usize, n: usize) {
    let rate = covered as f64 / n as f64;
    assert!(
        (0.90..=0.98).contains(&rate),
        "{what}: covered {covered}/{n}"
    );
}

#[test]
fn with_the_shared_terms_the_intervals_cover() {
    // White, dark, tile, gains (calibrated) and drift as the reference instrument has them.
    for (paper, geometries) in [
        ("SG", common::strategy2(3)),
        ("G", common::strategy2(2)),
        ("PPC", common::strategy2(5)),
        ("J1", common::strategy2(5)),
    ] {
        let seeds = 20_000..20_200;
        let (rho_s, rho_d, n) = coverage_shared(paper, &geometries, seeds.clone(), Errors::REAL);
        let (rho_s_before, rho_d_before, m) =
            coverage_independent(paper, &geometries, 200, Errors::REAL);
        println!(
            "{paper}: ρs covered {rho_s}/{n} (as independent {rho_s_before}/{m}), ρd {rho_d}/{n} ({rho_d_before}/{m})"
        );
        assert_coverage(&format!("{paper} ρs"), rho_s, n);
        assert_coverage(&format!("{paper} ρd"), rho_d, n);
    }
}

#[test]
fn the_budget_adds_up_to_the_covariance_diagonal() {
    for (k, (paper, geometries)) in [
        ("G", common::strategy2(2)),
        ("SG", common::strategy2(3)),
        ("PPC", common::strategy1_m12()),
        ("J2", common::strategy2(5)),
    ]
    .into_iter()
    .enumerate()
    {
        let p = common::reference(paper);
        let s = session(&p, &geometries, 30 + k as u64, Errors::REAL, true);
        let f = fit_with_shared(&s.observations, &s.shared, &options()).expect("a fit");
        // Every shared term the budget built is in the fit's budget, with the reading noise.
        for t in &s.shared {
            assert!(
                f.budget.iter().any(|b| b.name == t.name),
                "{paper}: {} missing",
                t.name
            );
        }
        assert!(
            f.budget
                .iter()
                .any(|b| budget::TermKind::of(&b.name) == budget::TermKind::ReadingNoise)
        );
        for i in 0..4 {
            if !(f.model.0[i] && f.identified(i)) {
                continue;
            }
            let sum: f64 = f.budget.iter().map(|t| t.variance[i]).sum();
            let diagonal = f.covariance[i][i];
            assert!(
                (sum - diagonal).abs() <= 1e-9 * diagonal.abs(),
                "{paper} parameter {i}: Σ terms {sum} vs covariance {diagonal}"
            );
        }
        let shares = budget::shares(&f);
        for i in 0..3 {
            let total: f64 = shares.iter().filter_map(|(_, s)| s[i]).sum();
            assert!(
                total == 0.0 || (total - 1.0).abs() < 1e-9,
                "{paper}: shares add to {total}"
            );
        }
    }
}

#[test]
fn a_reused_calibrations_age_widens_the_intervals_by_the_drift_term() {
    // The same instrument and noise (one seed), the calibration fresh or 4 h old.
    for (paper, geometries) in [("SG", common::strategy2(3)), ("PPC", common::strategy2(5))] {
        let p = common::reference(paper);
        let fresh = Errors::REAL;
        let aged = Errors {
            calibration_age_s: 4.0 * 3600.0,
            ..Errors::REAL
        };
        let s0 = session(&p, &geometries, 77, fresh, true);
        let f0 = fit_with_shared(&s0.observations, &s0.shared, &options()).unwrap();
        let s1 = session(&p, &geometries, 77, aged, true);
        let f1 = fit_with_shared(&s1.observations, &s1.shared, &options()).unwrap();
        let drift = |f: &FitResult, i: usize| {
            f.budget
                .iter()
                .find(|t| t.name == budget::LAMP_DRIFT)
                .map_or(0.0, |t| t.variance[i])
        };
        for (i, name, truth) in [(model::RHO_S, "ρs", p.rho_s), (model::RHO_D, "ρd", p.rho_d)] {
            let width = |f: &FitResult| f.ci95[i].map(|(lo, hi)| hi - lo).unwrap();
            // 4 h at 0.2 %/h: every reading 0.8 % off together, as the tile's 0.5 % is: 0.8 %
            // of the value (of the first pass's model, which scales the shared errors: within
            // 15 % of the final fit's for SG, whose ρs is loosely determined).
            let _ = truth;
            let expected = (f1.params.to_array()[i] * 0.002 * 4.0).powi(2);
            println!(
                "{paper} {name}: 95 % width {:.5} → {:.5}, drift variance {:.3e} → {:.3e} (0.8 % of the fitted value: {expected:.3e})",
                width(&f0),
                width(&f1),
                drift(&f0, i),
                drift(&f1, i)
            );
            assert!(width(&f1) > width(&f0), "{paper} {name}");
            assert!(
                (drift(&f1, i) / expected - 1.0).abs() < 0.15,
                "{paper} {name}: {} vs {expected}",
                drift(&f1, i)
            );
            assert!(
                drift(&f0, i) < 1e-3 * drift(&f1, i),
                "{paper} {name}: a fresh calibration's drift is negligible"
            );
            // The width grows as the variance does: by the drift term.
            let (v0, v1) = (f0.covariance[i][i], f1.covariance[i][i]);
            let predicted = width(&f0) * ((v0 + drift(&f1, i) - drift(&f0, i)) / v0).sqrt();
            assert!(
                (width(&f1) / predicted - 1.0).abs() < 0.05,
                "{paper} {name}: {} vs {predicted} ({v0} → {v1})",
                width(&f1)
            );
        }
        // And an aged calibration's intervals still cover, the drift realised.
        let (rho_s, rho_d, n) = coverage_shared(paper, &geometries, 40_000..40_200, aged);
        println!("{paper} with a 4 h old calibration: ρs covered {rho_s}/{n}, ρd {rho_d}/{n}");
        assert_coverage(&format!("{paper} aged ρs"), rho_s, n);
        assert_coverage(&format!("{paper} aged ρd"), rho_d, n);
    }
}
