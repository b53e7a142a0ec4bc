//! The instrument's own errors, drawn from the seed: range-gain ratios and the white tile
//! off by the stated spread over hundreds of seeds, each effect on its own random stream,
//! the arm zero error where the scene is looked at, and the sheet's spots changing when
//! the operator puts the sample back.
//!
//! Read at the detector itself (the firmware's hardware interface), so that a ratio is
//! what the hardware does, not what a calibration makes of it.

use firmware::config::InstrumentConfig;
use firmware::hardware::{Detector as _, Lamp as _};
use hil_sim::scene::{SamplePort, Scene};
use hil_sim::sheet::{SheetSpec, Stock};
use hil_sim::{InstrumentErrors, SimConfig, SimInstrument};
use protocol::Target;
use std::sync::Arc;

const SG: Stock = Stock {
    sigma_deg: 1.9,
    rho_s: 57.1,
    rho_d: 0.795,
    eta: 1.02,
};

fn instrument(
    port: SamplePort,
    seed: u64,
    errors: InstrumentErrors,
    noise_scale: f64,
) -> SimInstrument {
    let mut config = SimConfig {
        seed,
        errors,
        ..SimConfig::default()
    };
    config.detector.noise_scale = noise_scale;
    SimInstrument::new(port, config)
}

fn constant(radiance_factor: f64) -> SamplePort {
    SamplePort::new(Arc::new(move |_: f64, _: f64| radiance_factor))
}

/// The detector's ADC samples over `ms` with `target` on the port, on `range`, the lamp
/// on, the arms where they stand (30°, 30° at power-up), after the amplifier has settled
/// for as long as the firmware waits after a range change. `clock_us` is the hardware's
/// time.
fn samples(
    sim: &mut SimInstrument,
    target: Target,
    range: u8,
    ms: u64,
    clock_us: &mut u64,
) -> Vec<u32> {
    let hardware = sim.hardware_mut();
    hardware.set_lamp(true);
    hardware.place(target);
    hardware.advance_to(*clock_us);
    hardware.select_range(range);
    *clock_us += u64::from(InstrumentConfig::REFERENCE.range_settle_ms) * 1000;
    hardware.advance_to(*clock_us);
    hardware
        .drain_samples(&mut |_| {})
        .expect("the simulated ADC loses nothing");
    *clock_us += ms * 1000;
    hardware.advance_to(*clock_us);
    let mut taken = Vec::new();
    hardware
        .drain_samples(&mut |s| taken.push(s.counts))
        .expect("the simulated ADC loses nothing");
    taken
}

/// Mean signal above dark.
fn signal(sim: &mut SimInstrument, target: Target, range: u8, clock_us: &mut u64) -> f64 {
    let taken = samples(sim, target, range, 100, clock_us);
    let mean = taken.iter().map(|&s| f64::from(s)).sum::<f64>() / taken.len() as f64;
    mean - sim.hardware().detector().dark_offset_counts()
}

fn mean_and_sd(values: &[f64]) -> (f64, f64) {
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    (
        mean,
        (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt(),
    )
}

const SEEDS: u64 = 400;

#[test]
fn gain_ratios_are_off_by_the_drawn_amount_with_the_stated_spread() {
    let nominal = [1.0, 0.1, 0.01];
    for pct in [1.0, 2.5] {
        let p = pct / 100.0;
        let mut ratio_errors = [Vec::new(), Vec::new()];
        for seed in 0..SEEDS {
            let errors = InstrumentErrors {
                gain_ratio_sd: p,
                ..InstrumentErrors::default()
            };
            // A scene of 20 reads about 75 % of full scale on range 1 at 30°, 7.5 % on range 2;
            // the white tile 37 % on range 0, 3.7 % on range 1 (noiseless: rounding only).
            let mut bright = instrument(constant(20.0), seed, errors.clone(), 0.0);
            let mut white = instrument(constant(0.0), seed, errors, 0.0);
            let mut clock = 0;
            let r1 = signal(&mut white, Target::WhiteReference, 1, &mut clock)
                / signal(&mut white, Target::WhiteReference, 0, &mut clock);
            let r2 = signal(&mut bright, Target::Sample, 2, &mut clock)
                / signal(&mut bright, Target::Sample, 1, &mut clock);
            let measured = [
                r1 / (nominal[1] / nominal[0]) - 1.0,
                r2 / (nominal[2] / nominal[1]) - 1.0,
            ];
            // What the hardware does is what was drawn.
            let truth = &white.truth().relative_gains;
            assert_eq!(truth[0], 1.0, "range 0 is the reference");
            for k in 0..2 {
                let drawn = truth[k + 1] / truth[k] / (nominal[k + 1] / nominal[k]) - 1.0;
                assert!(
                    (measured[k] - drawn).abs() < 5e-4,
                    "seed {seed} ratio {k}: measured {:.5} drawn {drawn:.5}",
                    measured[k]
                );
                ratio_errors[k].push(measured[k]);
            }
        }
        let se_sd = p / (2.0 * SEEDS as f64).sqrt();
        for (k, errors) in ratio_errors.iter().enumerate() {
            let (mean, sd) = mean_and_sd(errors);
            eprintln!(
                "gain error {pct} %: ratio {}/{k} off by {:.3} % ± {:.3} % over {SEEDS} seeds",
                k + 1,
                mean * 100.0,
                sd * 100.0
            );
            assert!(
                (sd - p).abs() < 4.0 * se_sd,
                "ratio {k}: spread {:.3} % for {pct} %",
                sd * 100.0
            );
            assert!(
                mean.abs() < 4.0 * p / (SEEDS as f64).sqrt(),
                "ratio {k}: mean {mean}"
            );
        }
        let n = SEEDS as f64;
        let (m0, s0) = mean_and_sd(&ratio_errors[0]);
        let (m1, s1) = mean_and_sd(&ratio_errors[1]);
        let corr = ratio_errors[0]
            .iter()
            .zip(&ratio_errors[1])
            .map(|(a, b)| (a - m0) * (b - m1))
            .sum::<f64>()
            / ((n - 1.0) * s0 * s1);
        assert!(
            corr.abs() < 4.0 / n.sqrt(),
            "the two ratios are drawn independently: r = {corr}"
        );
    }
}

#[test]
fn the_tile_is_off_its_certificate_by_the_stated_spread() {
    for pct in [0.5, 2.0] {
        let p = pct / 100.0;
        let mut ideal = instrument(constant(0.0), 0, InstrumentErrors::default(), 0.0);
        let mut clock = 0;
        let certificate_signal = signal(&mut ideal, Target::WhiteReference, 0, &mut clock);
        let mut errors = Vec::new();
        for seed in 0..SEEDS {
            let mut sim = instrument(
                constant(0.0),
                seed,
                InstrumentErrors {
                    tile_sd: p,
                    ..InstrumentErrors::default()
                },
                0.0,
            );
            let truth =
                sim.truth().tile_radiance_factor / hil_sim::scene::WHITE_TILE_RADIANCE_FACTOR - 1.0;
            let mut clock = 0;
            let measured =
                signal(&mut sim, Target::WhiteReference, 0, &mut clock) / certificate_signal - 1.0;
            assert!(
                (measured - truth).abs() < 1e-4,
                "seed {seed}: the detector sees {measured:.5}, drawn {truth:.5}"
            );
            errors.push(truth);
        }
        let (mean, sd) = mean_and_sd(&errors);
        eprintln!(
            "tile error {pct} %: {:.3} % ± {:.3} % over {SEEDS} seeds",
            mean * 100.0,
            sd * 100.0
        );
        assert!(
            (sd - p).abs() < 4.0 * p / (2.0 * SEEDS as f64).sqrt(),
            "spread {:.3} % for {pct} %",
            sd * 100.0
        );
        assert!(mean.abs() < 4.0 * p / (SEEDS as f64).sqrt());
    }
}

#[test]
fn each_effect_draws_from_its_own_stream() {
    let sheet = || SamplePort::with_spots(Arc::new(SheetSpec::tsl(SG)), 0);
    for seed in [3, 17, 101, 4242] {
        let readings = |port: SamplePort, errors: InstrumentErrors, target: Target, range: u8| {
            let mut sim = instrument(port, seed, errors, 1.0);
            let mut clock = 0;
            samples(&mut sim, target, range, 300, &mut clock)
        };
        let base = InstrumentErrors::default();
        let gains = InstrumentErrors {
            gain_ratio_sd: 0.02,
            ..base.clone()
        };
        let tile = InstrumentErrors {
            tile_sd: 0.02,
            ..base.clone()
        };
        // A gain error leaves range 0 and the noise as they were.
        assert_eq!(
            readings(sheet(), base.clone(), Target::WhiteReference, 0),
            readings(sheet(), gains.clone(), Target::WhiteReference, 0)
        );
        // A tile error leaves the sample's readings as they were.
        assert_eq!(
            readings(sheet(), base.clone(), Target::Sample, 0),
            readings(sheet(), tile.clone(), Target::Sample, 0)
        );
        // A varying sheet leaves the white tile's readings (the detector noise) as they were.
        let varied = || {
            SamplePort::with_spots(
                Arc::new(SheetSpec {
                    spot_variation: 0.2,
                    ..SheetSpec::tsl(SG)
                }),
                seed,
            )
        };
        assert_eq!(
            readings(sheet(), tile.clone(), Target::WhiteReference, 0),
            readings(varied(), tile.clone(), Target::WhiteReference, 0)
        );
        // Changing an effect's size scales its draw, never redraws it.
        let truth =
            |errors: InstrumentErrors| instrument(constant(1.0), seed, errors, 1.0).truth().clone();
        let small = truth(InstrumentErrors {
            gain_ratio_sd: 0.01,
            tile_sd: 0.01,
            ..base.clone()
        });
        let large = truth(InstrumentErrors {
            gain_ratio_sd: 0.02,
            tile_sd: 0.005,
            ..base.clone()
        });
        let z = |t: &hil_sim::Truth, sd: f64| (t.relative_gains[1] / 0.1 - 1.0) / sd;
        assert!((z(&small, 0.01) - z(&large, 0.02)).abs() < 1e-9);
        let zt = |t: &hil_sim::Truth, sd: f64| (t.tile_radiance_factor / 0.99 - 1.0) / sd;
        assert!((zt(&small, 0.01) - zt(&large, 0.005)).abs() < 1e-9);
        // And link faults leave the detector alone.
        let mut faulty = SimConfig {
            seed,
            ..SimConfig::default()
        };
        faulty.faults.corrupt = 0.01;
        faulty.faults.drop = 0.01;
        let mut a = SimInstrument::new(sheet(), faulty);
        let mut clock = 0;
        assert_eq!(
            samples(&mut a, Target::Sample, 0, 300, &mut clock),
            readings(sheet(), base, Target::Sample, 0)
        );
    }
}

#[test]
fn the_arm_zero_error_is_where_the_scene_is_looked_at() {
    for offset in [-0.5, -0.1, 0.05, 0.3, 1.0] {
        for seed in [1, 2] {
            let spec = SheetSpec::tsl(SG);
            let mut shifted = instrument(
                SamplePort::with_spots(Arc::new(spec), seed),
                seed,
                InstrumentErrors {
                    theta_r_offset_deg: offset,
                    ..InstrumentErrors::default()
                },
                1.0,
            );
            let sheet = spec.spot(seed, 0);
            // The arms stand at (30°, 30°): the detector truly looks from 30° + offset.
            let expected =
                shifted
                    .hardware()
                    .detector()
                    .seen_radiance_factor(&sheet, 30.0, 30.0 + offset);
            let seen = shifted.hardware_mut().seen_radiance_factor();
            assert_eq!(seen, expected, "offset {offset}");
            assert_ne!(
                seen,
                shifted
                    .hardware()
                    .detector()
                    .seen_radiance_factor(&sheet, 30.0, 30.0),
                "{offset}"
            );
            assert_eq!(shifted.truth().theta_r_offset_deg, offset);
        }
    }
}

#[test]
fn the_sample_lands_on_a_new_spot_after_the_white_tile_and_on_request() {
    for seed in 0..20 {
        let spec = SheetSpec {
            spot_variation: 0.1,
            ..SheetSpec::tsl(SG)
        };
        let mut sim = instrument(
            SamplePort::with_spots(Arc::new(spec), seed),
            seed,
            InstrumentErrors::default(),
            1.0,
        );
        let seen = |sim: &mut SimInstrument| sim.hardware_mut().seen_radiance_factor();
        let expected = |sim: &SimInstrument, spot: u32| {
            sim.hardware()
                .detector()
                .seen_radiance_factor(&spec.spot(seed, spot), 30.0, 30.0)
        };
        assert_eq!(sim.hardware().spot(), 0);
        assert_eq!(seen(&mut sim), expected(&sim, 0));
        // Sample again without the tile in between: the same spot.
        sim.hardware_mut().place(Target::Sample);
        assert_eq!(sim.hardware().spot(), 0);
        sim.hardware_mut().place(Target::WhiteReference);
        assert!(
            (seen(&mut sim) - 0.99).abs() < 1e-12,
            "the tile is on the port"
        );
        sim.hardware_mut().place(Target::Sample);
        assert_eq!(sim.hardware().spot(), 1);
        assert_eq!(seen(&mut sim), expected(&sim, 1));
        assert_ne!(expected(&sim, 0), expected(&sim, 1));
        sim.next_spot();
        assert_eq!(sim.hardware().spot(), 2);
        assert_eq!(seen(&mut sim), expected(&sim, 2));
    }
    // A sample that is the same everywhere stays the same.
    let mut plain = instrument(constant(0.5), 1, InstrumentErrors::default(), 1.0);
    plain.next_spot();
    assert_eq!(plain.hardware_mut().seen_radiance_factor(), 0.5);
    let _ = Scene::radiance_factor(&SheetSpec::tsl(SG).spot(1, 0), 20.0, 20.0);
}

/// Switched on again (a session resumed after a crash), the instrument is the same one —
/// its drawn gains, tile and arm zero, its sheet — but its detector noise is not its first
/// run's again: that replay made a resumed session read the sample with the very noise of
/// its first run's dark and white readings, and fail the goodness of fit.
#[test]
fn an_instrument_switched_on_again_keeps_its_errors_and_draws_new_noise() {
    let errors = InstrumentErrors {
        gain_ratio_sd: 0.01,
        tile_sd: 0.005,
        theta_r_offset_deg: 0.0,
        theta_r_offset_sd_deg: 0.1,
    };
    let start = |power_on: u64| {
        let config = SimConfig {
            seed: 7,
            power_on,
            errors: errors.clone(),
            ..SimConfig::default()
        };
        SimInstrument::new(
            SamplePort::with_spots(Arc::new(SheetSpec::tsl(SG)), 0),
            config,
        )
    };
    let (mut first, mut again, mut first_twin) = (start(0), start(1), start(0));
    assert_eq!(first.truth(), again.truth(), "the same instrument");
    let mut clocks = [0u64; 3];
    let a = samples(&mut first, Target::Sample, 0, 50, &mut clocks[0]);
    let b = samples(&mut again, Target::Sample, 0, 50, &mut clocks[1]);
    let c = samples(&mut first_twin, Target::Sample, 0, 50, &mut clocks[2]);
    assert_eq!(a, c, "the same power-on repeats its noise exactly");
    assert_ne!(a, b, "another power-on draws other noise");
    let mean = |v: &[u32]| v.iter().map(|&x| f64::from(x)).sum::<f64>() / v.len() as f64;
    let sd = detector_sd(&a);
    assert!(
        (mean(&a) - mean(&b)).abs() < 6.0 * sd * (2.0 / a.len() as f64).sqrt(),
        "the same signal: {} against {}",
        mean(&a),
        mean(&b)
    );
}

/// The samples' standard deviation, counts.
fn detector_sd(taken: &[u32]) -> f64 {
    let mean = taken.iter().map(|&x| f64::from(x)).sum::<f64>() / taken.len() as f64;
    (taken
        .iter()
        .map(|&x| (f64::from(x) - mean).powi(2))
        .sum::<f64>()
        / (taken.len() - 1) as f64)
        .sqrt()
}
