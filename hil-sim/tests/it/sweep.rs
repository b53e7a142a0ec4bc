//! Sweeps on the simulated instrument: the physics of a moving detector as the firmware's
//! sweeps read it, over many seeds.
//!
//! - A bin of a known scene (linear, Gaussian in θr) reads its interval's mean through the
//!   acceptance, lagged by the amplifier's v·τ, within the noise: over seeds the error's
//!   mean is ≈ 0 and its spread is the bin's reported std/√blocks.
//! - The lag: a sweep forwards and backwards across a narrow peak puts it v·τ late each
//!   way, for the range in use.
//! - A bright specular peak seen from the most sensitive range switches ranges with blocks
//!   blanked; read without blanking, the blocks within a range's settling time are wrong.
//! - A scene beyond the least sensitive range's full scale gives SATURATED bins, never a
//!   clipped value unflagged.
//! - Random sweeps: the bins tile the sweep, every bin's interval is the detector arm's
//!   step counts at its blocks' ends; the same seed gives the same bins.
//!
//! The host is a minimal one written against the wire contract (the host crate is not a
//! dependency of the simulator): it heartbeats every 200 ms of device time.

use firmware::config::InstrumentConfig;
use firmware::hardware::{Detector as _, Lamp as _};
use hil_sim::scene::{SamplePort, Scene};
use hil_sim::{SimConfig, SimInstrument};
use proptest::prelude::*;
use protocol::*;
use std::sync::Arc;
use std::time::Duration;

const CONFIG: InstrumentConfig = InstrumentConfig::REFERENCE;
const FULL_SCALE: f64 = 65_535.0;
const BLOCK_S: f64 = CONFIG.detector_block_us as f64 * 1e-6;
const HEARTBEAT_US: u64 = 200_000;

struct Host {
    sim: SimInstrument,
    seq: u32,
    decoder: FrameDecoder,
    messages: Vec<DeviceMessage>,
}

impl Host {
    /// A simulated instrument with `scene` on the port, homed, the lamp on.
    fn ready(scene: Arc<dyn Scene>, seed: u64, noise_scale: f64) -> Host {
        Host::ready_on(scene, seed, noise_scale, CONFIG)
    }

    /// The same on an instrument of `instrument` (its amplifier's time constants).
    fn ready_on(
        scene: Arc<dyn Scene>,
        seed: u64,
        noise_scale: f64,
        instrument: InstrumentConfig,
    ) -> Host {
        let mut config = SimConfig {
            seed,
            instrument,
            ..SimConfig::default()
        };
        config.detector.noise_scale = noise_scale;
        let mut host = Host {
            sim: SimInstrument::new(SamplePort::new(scene), config),
            seq: 0,
            decoder: FrameDecoder::new(),
            messages: Vec::new(),
        };
        assert!(matches!(
            host.request(
                Command::Hello {
                    protocol_version: PROTOCOL_VERSION
                },
                1.0
            ),
            Reply::Hello(_)
        ));
        assert!(matches!(host.request(Command::Home, 60.0), Reply::Homed(_)));
        assert!(matches!(
            host.request(Command::SetLamp { on: true }, 1.0),
            Reply::Ack
        ));
        host
    }

    fn send(&mut self, command: Command) -> u32 {
        self.seq += 1;
        let mut buf = [0u8; MAX_FRAME_LEN];
        let frame = encode_frame(
            &Request {
                seq: self.seq,
                command,
            },
            &mut buf,
        )
        .expect("frame");
        self.sim.write(frame).expect("the cable is in");
        self.seq
    }

    /// Read for up to 10 ms of device time, keeping every message; a heartbeat when due.
    fn pump(&mut self, next_heartbeat_us: &mut u64) {
        let mut buf = [0u8; 512];
        let n = self
            .sim
            .read(&mut buf, Duration::from_millis(10))
            .expect("the cable is in");
        for &byte in &buf[..n] {
            if let Some(Ok(message)) = self.decoder.push::<DeviceMessage>(byte) {
                self.messages.push(message);
            }
        }
        if self.sim.device_time_us() >= *next_heartbeat_us {
            *next_heartbeat_us = self.sim.device_time_us() + HEARTBEAT_US;
            self.send(Command::Heartbeat);
        }
    }

    fn request(&mut self, command: Command, wait_s: f64) -> Reply {
        let from = self.messages.len();
        let seq = self.send(command.clone());
        let deadline = self.sim.device_time_us() + (wait_s * 1e6) as u64;
        let mut heartbeat = self.sim.device_time_us() + HEARTBEAT_US;
        while self.sim.device_time_us() < deadline {
            self.pump(&mut heartbeat);
            let reply = self.messages[from..].iter().find_map(|m| match m {
                DeviceMessage::Reply { seq: got, result } if *got == seq => Some(result.clone()),
                _ => None,
            });
            if let Some(result) = reply {
                return result.unwrap_or_else(|e| panic!("{command:?} refused: {e:?}"));
            }
        }
        panic!("no answer to {command:?}");
    }

    /// Run `sweep` to its `SweepDone`: the plan and the bins.
    fn sweep(&mut self, sweep: Sweep) -> (SweepPlan, Vec<SweepBin>) {
        let from = self.messages.len();
        let Reply::Sweep(plan) = self.request(Command::Sweep(sweep), 1.0) else {
            panic!("not a sweep plan")
        };
        let deadline = self.sim.device_time_us() + u64::from(plan.duration_ms) * 1000 + 2_000_000;
        let mut heartbeat = self.sim.device_time_us() + HEARTBEAT_US;
        let done = |messages: &[DeviceMessage]| {
            messages.iter().any(|m| matches!(m, DeviceMessage::SweepDone { sweep_id, .. } if *sweep_id == sweep.sweep_id))
        };
        while !done(&self.messages[from..]) {
            assert!(
                self.sim.device_time_us() < deadline,
                "no SweepDone for {sweep:?}"
            );
            self.pump(&mut heartbeat);
        }
        let bins = self.messages[from..]
            .iter()
            .filter_map(|m| match m {
                DeviceMessage::SweepBin(bin) if bin.sweep_id == sweep.sweep_id => Some(*bin),
                _ => None,
            })
            .collect();
        (plan, bins)
    }

    /// The counts a bin on `range` would read for a radiance factor seen of `seen` at θi
    /// (dark included, the lamp's drift at the bin's time).
    fn counts(&self, seen: f64, theta_i_deg: f64, range: u8, device_time_us: u64) -> f64 {
        let detector = self.sim.hardware().detector();
        let lamp = detector.lamp_output(device_time_us as f64 * 1e-6);
        detector.dark_offset_counts()
            + detector.signal_counts(seen, theta_i_deg, usize::from(range), lamp)
    }

    /// The mean over θr in [a, b] of the scene through the acceptance (a dense midpoint sum).
    fn interval_mean(&self, scene: &dyn Scene, theta_i_deg: f64, a: f64, b: f64) -> f64 {
        let detector = self.sim.hardware().detector();
        let n = 64;
        (0..n)
            .map(|k| {
                detector.seen_radiance_factor(
                    scene,
                    theta_i_deg,
                    a + (b - a) * (k as f64 + 0.5) / n as f64,
                )
            })
            .sum::<f64>()
            / n as f64
    }

    /// What `bin` should read: the scene's mean over its interval, shifted back along the
    /// travel by the amplifier's lag v·τ (v the bin's mean speed), on the bin's range.
    fn expected_counts(&self, scene: &dyn Scene, sweep: &Sweep, bin: &SweepBin) -> f64 {
        let (a, b) = (bin.start.deg(), bin.end.deg());
        let lag = lag_deg(bin);
        let direction = (b - a).signum();
        let seen = self.interval_mean(
            scene,
            sweep.theta_i.deg(),
            a - direction * lag,
            b - direction * lag,
        );
        self.counts(seen, sweep.theta_i.deg(), bin.range, bin.device_time_us)
    }
}

impl Host {
    /// A bin's value is right: a whole bin its interval's mean (lagged) within 5 σ of the
    /// noise; one that lost blocks (BLANKED: its kept blocks cover part of the interval)
    /// within 5 σ of the range the scene takes over the interval.
    fn check_value(&self, scene: &dyn Scene, sweep: &Sweep, bin: &SweepBin, context: &str) {
        let detector = self.sim.hardware().detector();
        let expected = self.expected_counts(scene, sweep, bin);
        let sigma = detector.sample_sigma_counts(expected - detector.dark_offset_counts())
            / f64::from(bin.blocks).sqrt();
        let mean = f64::from(bin.mean_counts);
        if bin.flags == 0 {
            assert!(
                (mean - expected).abs() < 5.0 * sigma,
                "{context}: a bin off by {:.1} σ: {bin:?}, expected {expected:.0}",
                (mean - expected) / sigma
            );
            return;
        }
        let (a, b) = (bin.start.deg(), bin.end.deg());
        let lag = (b - a).signum() * lag_deg(bin);
        let theta_i = sweep.theta_i.deg();
        let values: Vec<f64> = (0..=16)
            .map(|k| a + (b - a) * k as f64 / 16.0 - lag)
            .map(|theta_r| {
                self.counts(
                    detector.seen_radiance_factor(scene, theta_i, theta_r),
                    theta_i,
                    bin.range,
                    bin.device_time_us,
                )
            })
            .collect();
        let (lo, hi) = values
            .iter()
            .fold((f64::MAX, f64::MIN), |(lo, hi), &v| (lo.min(v), hi.max(v)));
        let sigma = detector.sample_sigma_counts(hi - detector.dark_offset_counts())
            / f64::from(bin.blocks).sqrt();
        assert!(
            mean > lo - 5.0 * sigma && mean < hi + 5.0 * sigma,
            "{context}: a bin that lost blocks reads {mean:.0}, outside its interval's {lo:.0} … {hi:.0} (σ {sigma:.0}): {bin:?}"
        );
    }
}

/// The amplifier's lag over `bin`, degrees: its mean speed times τ of its range.
fn lag_deg(bin: &SweepBin) -> f64 {
    let speed = (bin.end.deg() - bin.start.deg()).abs() / (f64::from(bin.blocks.max(1)) * BLOCK_S);
    speed * f64::from(CONFIG.detector_ranges[usize::from(bin.range)].time_constant_us) * 1e-6
}

fn sweep(
    sweep_id: u16,
    theta_i_deg: f64,
    from_deg: f64,
    to_deg: f64,
    speed_deg_per_s: f64,
    bin_ticks: u16,
    range: Option<u8>,
) -> Sweep {
    Sweep {
        sweep_id,
        theta_i: Angle::from_deg(theta_i_deg).expect("in range"),
        from: Angle::from_deg(from_deg).expect("in range"),
        to: Angle::from_deg(to_deg).expect("in range"),
        speed_mdeg_per_s: (speed_deg_per_s * 1000.0).round() as u32,
        bin_ticks,
        range,
        target: Target::Sample,
    }
}

fn mean_and_sd(values: &[f64]) -> (f64, f64) {
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    (
        mean,
        (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt(),
    )
}

/// A Gaussian peak in θr on a diffuse level (radiance factors).
fn peak(base: f64, height: f64, center_deg: f64, sd_deg: f64) -> Arc<dyn Scene> {
    Arc::new(move |_: f64, theta_r: f64| {
        base + height * (-0.5 * ((theta_r - center_deg) / sd_deg).powi(2)).exp()
    })
}

const SEEDS: u64 = 20;

#[test]
fn a_bin_of_a_linear_scene_reads_its_intervals_mean_within_the_noise() {
    // 0.5 at θr = 0 rising by 0.01 per degree: 28 % to 64 % of full scale at θi = 30° on
    // range 0. 10 °/s and 0.1° bins: 10 blocks a bin, so the reported std means something.
    let scene: Arc<dyn Scene> = Arc::new(|_: f64, theta_r: f64| 0.5 + 0.01 * theta_r);
    let (mut errors, mut z) = (Vec::new(), Vec::new());
    let (mut lag_effect, mut blocks) = (Vec::new(), Vec::new());
    for seed in 0..SEEDS {
        let mut host = Host::ready(scene.clone(), seed, 1.0);
        let s = sweep(1, 30.0, 5.0, 65.0, 10.0, 8, None);
        let (plan, bins) = host.sweep(s);
        assert_eq!(bins.len(), usize::from(plan.bins));
        for bin in bins.iter().filter(|b| b.flags == 0) {
            assert!(bin.blocks >= 3, "{bin:?}");
            let expected = host.expected_counts(scene.as_ref(), &s, bin);
            let error = f64::from(bin.mean_counts) - expected;
            errors.push(error);
            z.push(error / (f64::from(bin.std_counts) / f64::from(bin.blocks).sqrt()));
            blocks.push(f64::from(bin.blocks));
            let unlagged = host.counts(
                host.interval_mean(scene.as_ref(), 30.0, bin.start.deg(), bin.end.deg()),
                30.0,
                bin.range,
                bin.device_time_us,
            );
            lag_effect.push(expected - unlagged);
        }
    }
    let (mean, sd) = mean_and_sd(&errors);
    let (z_mean, z_sd) = mean_and_sd(&z);
    let n = errors.len() as f64;
    eprintln!(
        "linear scene: {n} bins, error {mean:.2} ± {sd:.1} counts (mean ± sd), z {z_mean:.3} ± {z_sd:.3}, lag's effect {:.2} counts",
        mean_and_sd(&lag_effect).0
    );
    assert!(n > 0.9 * (SEEDS * 600) as f64, "{n} clean bins");
    assert!(
        mean.abs() < 4.0 * sd / n.sqrt(),
        "mean error {mean} counts, sd {sd}: a bias"
    );
    // The spread is the reported std/√blocks: z is Student's t with blocks − 1 degrees of
    // freedom (the std of ten blocks is itself uncertain), whose spread is √((n−1)/(n−3)).
    let t_sd = mean_and_sd(
        &blocks
            .iter()
            .map(|&b| ((b - 1.0) / (b - 3.0)).sqrt())
            .collect::<Vec<_>>(),
    )
    .0;
    eprintln!("  z spread {z_sd:.3} against Student's {t_sd:.3}");
    assert!(z_mean.abs() < 4.0 / n.sqrt(), "z mean {z_mean}");
    assert!(
        (z_sd / t_sd - 1.0).abs() < 0.05,
        "z spread {z_sd}, Student's {t_sd}"
    );
}

#[test]
fn a_bin_across_a_gaussian_lobe_reads_its_intervals_mean_within_the_noise() {
    // A lobe 2° wide in θr reaching 60 % of full scale on range 1 (so ranges switch on its
    // way up and down), at 20 °/s, 0.1° bins (5 blocks).
    let scene = peak(0.4, 24.0, 40.0, 2.0);
    let mut z = Vec::new();
    // Each sweep's mean z: a sweep's bins share its session's errors (lamp, gains), so
    // they are not independent draws and the bias is judged by the sweeps' spread.
    let mut sweep_means = Vec::new();
    let mut ranges = std::collections::BTreeSet::new();
    for seed in 0..SEEDS {
        let first = z.len();
        let mut host = Host::ready(scene.clone(), 100 + seed, 1.0);
        let s = if seed % 2 == 0 {
            sweep(2, 40.0, 25.0, 55.0, 20.0, 8, None)
        } else {
            sweep(2, 40.0, 55.0, 25.0, 20.0, 8, None)
        };
        let (_, bins) = host.sweep(s);
        for bin in bins.iter().filter(|b| b.flags == 0) {
            ranges.insert(bin.range);
            let expected = host.expected_counts(scene.as_ref(), &s, bin);
            // Against the model's noise (the reported std also holds the lobe's change across
            // the bin, which is no noise).
            let detector = host.sim.hardware().detector();
            let sigma = detector.sample_sigma_counts(expected - detector.dark_offset_counts())
                / f64::from(bin.blocks).sqrt();
            z.push((f64::from(bin.mean_counts) - expected) / sigma);
        }
        sweep_means.push(mean_and_sd(&z[first..]).0);
    }
    let (z_mean, z_sd) = mean_and_sd(&z);
    let (_, between_sd) = mean_and_sd(&sweep_means);
    // The standard error of the mean z: from the sweeps' spread, and never below that of
    // independent bins.
    let standard_error = (between_sd / (SEEDS as f64).sqrt()).max(1.0 / (z.len() as f64).sqrt());
    eprintln!(
        "gaussian lobe: {} bins on ranges {ranges:?}, z {z_mean:.3} ± {z_sd:.3}, its standard error {standard_error:.4} ({SEEDS} sweeps)",
        z.len()
    );
    assert!(
        ranges.len() >= 2,
        "the lobe is read on several ranges: {ranges:?}"
    );
    assert!(
        z_mean.abs() < 4.0 * standard_error,
        "z mean {z_mean} ({standard_error:.4} its standard error): a bias"
    );
    assert!((0.9..1.1).contains(&z_sd), "z spread {z_sd}");
}

/// The centroid of a peak from a sweep's bins, degrees: bins within `half_width` of
/// `center`, weighted by their counts above `base_counts` and their width.
fn centroid(bins: &[SweepBin], base_counts: f64, center: f64, half_width: f64) -> f64 {
    let (mut moment, mut mass) = (0.0, 0.0);
    for bin in bins {
        let (a, b) = (bin.start.deg(), bin.end.deg());
        let mid = 0.5 * (a + b);
        if (mid - center).abs() > half_width {
            continue;
        }
        let weight = (f64::from(bin.mean_counts) - base_counts) * (b - a).abs();
        moment += weight * mid;
        mass += weight;
    }
    moment / mass
}

/// The reference ranges with an ideal amplifier (τ = 0): what a sweep would read with no lag.
static IDEAL_RANGES: [DetectorRange; 3] = {
    let mut ranges = firmware::config::REFERENCE_RANGES;
    let mut k = 0;
    while k < ranges.len() {
        ranges[k].time_constant_us = 0.0;
        k += 1;
    }
    ranges
};

fn ideal_amplifier() -> InstrumentConfig {
    InstrumentConfig {
        detector_ranges: &IDEAL_RANGES,
        ..CONFIG
    }
}

/// The peak's centroid from a sweep there and back on a forced `range`, each way relative
/// to `center` along the travel (positive: late): (forwards, backwards).
fn centroids(
    host: &mut Host,
    range: u8,
    base_radiance_factor: f64,
    center: f64,
    start: f64,
    speed: f64,
) -> (f64, f64) {
    let base = host.counts(base_radiance_factor, 40.0, range, host.sim.device_time_us());
    let (_, there) = host.sweep(sweep(3, 40.0, start, 60.0, speed, 6, Some(range)));
    let (_, back) = host.sweep(sweep(4, 40.0, 60.0, start, speed, 6, Some(range)));
    assert!(
        there.iter().chain(&back).all(|b| b.flags == 0),
        "forced range {range}: no flag"
    );
    (
        centroid(&there, base, center, 4.0) - center,
        center - centroid(&back, base, center, 4.0),
    )
}

#[test]
fn a_narrow_peak_is_read_v_tau_late_in_each_direction_on_the_range_in_use() {
    // A peak 0.5° wide (1.1° seen through the 1° acceptance) near 40°, crossed at 60 °/s in
    // the cruise of a 20° → 60° sweep, forwards and backwards, on a forced range where it
    // reads 70 % of full scale. The centroid of the bins is where the peak appears; against
    // the same sweeps with an ideal amplifier, it is late by v·τ each way. (With an ideal
    // amplifier it is late by about 0.1 microstep too: the arm stands on whole microsteps
    // for unequal parts of a bin, so a bin's mean position is not quite its interval's
    // middle; that is the stepper's, under the angle's resolution, and not the subject
    // here.) Noiseless, so that even range 2's 0.0003° shows, and with the peak and the
    // sweep's start moved by fractions of a microstep from run to run. With noise: the next
    // test.
    let speed = 60.0;
    for range in [0u8, 1, 2] {
        let tau_us = f64::from(CONFIG.detector_ranges[usize::from(range)].time_constant_us);
        let expected_lag = speed * tau_us * 1e-6;
        let gain = 10f64.powi(i32::from(range));
        let (mut forward, mut backward, mut stepper) = (Vec::new(), Vec::new(), Vec::new());
        for k in 0..8 {
            let center = 40.0 + 0.00137 * k as f64;
            let scene = peak(0.05 * gain, 3.0 * gain, center, 0.5);
            let start = 20.0 + 0.0125 * k as f64;
            let lagged = centroids(
                &mut Host::ready(scene.clone(), 200 + k, 0.0),
                range,
                0.05 * gain,
                center,
                start,
                speed,
            );
            let ideal = centroids(
                &mut Host::ready_on(scene.clone(), 200 + k, 0.0, ideal_amplifier()),
                range,
                0.05 * gain,
                center,
                start,
                speed,
            );
            forward.push(lagged.0 - ideal.0);
            backward.push(lagged.1 - ideal.1);
            stepper.extend([ideal.0, ideal.1]);
        }
        let (lag_forward, sd_forward) = mean_and_sd(&forward);
        let (lag_backward, sd_backward) = mean_and_sd(&backward);
        let (stepper_late, _) = mean_and_sd(&stepper);
        eprintln!(
            "range {range}: v·τ {expected_lag:.5}°, measured late by {lag_forward:.5}° ± {sd_forward:.5} forwards, {lag_backward:.5}° ± {sd_backward:.5} backwards (ideal amplifier: {stepper_late:.5}° late)"
        );
        let tolerance = (0.05 * expected_lag).max(0.00005);
        for (lag, sd) in [(lag_forward, sd_forward), (lag_backward, sd_backward)] {
            assert!(
                (lag - expected_lag).abs() < tolerance,
                "range {range}: late by {lag}° (sd {sd}), v·τ {expected_lag}°"
            );
        }
        assert!(
            stepper_late.abs() < 0.25 * 0.0125,
            "the stepper's part {stepper_late}°: a quarter microstep at most"
        );
    }
}

#[test]
fn with_noise_the_lag_on_the_most_sensitive_range_is_v_tau_within_the_noise() {
    let speed = 60.0;
    let expected_lag = speed * f64::from(CONFIG.detector_ranges[0].time_constant_us) * 1e-6;
    let scene = peak(0.05, 3.0, 40.0, 0.5);
    let ideal = centroids(
        &mut Host::ready_on(scene.clone(), 0, 0.0, ideal_amplifier()),
        0,
        0.05,
        40.0,
        20.0,
        speed,
    );
    let mut lags = Vec::new();
    for seed in 0..SEEDS {
        let (forward, backward) = centroids(
            &mut Host::ready(scene.clone(), 250 + seed, 1.0),
            0,
            0.05,
            40.0,
            20.0,
            speed,
        );
        lags.extend([forward - ideal.0, backward - ideal.1]);
    }
    let (lag, sd) = mean_and_sd(&lags);
    let error = sd / (lags.len() as f64).sqrt();
    eprintln!(
        "range 0 with noise: v·τ {expected_lag:.5}°, measured {lag:.5}° ± {error:.5} (sd of one sweep {sd:.5}°)"
    );
    assert!(
        (lag - expected_lag).abs() < 4.0 * error,
        "late by {lag}° ± {error}, v·τ {expected_lag}°"
    );
    // And it is there: 0 is far outside.
    assert!(lag > 8.0 * error, "{lag} ± {error}");
}

#[test]
fn a_bright_specular_peak_switches_range_with_blocks_blanked_and_no_kept_bin_is_off() {
    // A G-like lobe (radiance factor 40 on 0.8 diffuse, 1.6° wide) read from the diffuse
    // side on the most sensitive range: up to the least sensitive and back, at 60 °/s.
    let scene = peak(0.8, 40.0, 45.0, 1.6);
    let mut switches = 0;
    for seed in 0..SEEDS {
        let mut host = Host::ready(scene.clone(), 300 + seed, 1.0);
        let s = sweep(5, 45.0, 30.0, 60.0, 60.0, 8, None);
        let (_, bins) = host.sweep(s);
        assert_eq!(
            bins.first().map(|b| b.range),
            Some(0),
            "starts on the most sensitive range"
        );
        let used: Vec<u8> = bins
            .iter()
            .filter(|b| b.flags & SweepBin::EMPTY == 0)
            .map(|b| b.range)
            .collect();
        assert!(
            used.contains(&2),
            "the peak needs the least sensitive range: {used:?}"
        );
        for pair in bins.windows(2) {
            if pair[0].range != pair[1].range {
                switches += 1;
                // The blocks after a switch are blanked: a bin next to it lost some.
                assert!(
                    (pair[0].flags | pair[1].flags) & SweepBin::BLANKED != 0,
                    "seed {seed}: a switch {} → {} with nothing blanked: {pair:?}",
                    pair[0].range,
                    pair[1].range
                );
            }
        }
        for bin in bins
            .iter()
            .filter(|b| b.flags & (SweepBin::EMPTY | SweepBin::SATURATED) == 0)
        {
            host.check_value(scene.as_ref(), &s, bin, &format!("seed {seed}"));
        }
    }
    assert!(switches >= 4 * SEEDS, "{switches} switches");
}

/// Blocks read straight from the simulated detector (no firmware): at rest on a constant
/// scene, on `before`, then switched to `after`; the block values after the switch.
fn blocks_after_a_switch(
    radiance_factor: f64,
    before: u8,
    after: u8,
    seed: u64,
) -> (Vec<f64>, f64) {
    let scene: Arc<dyn Scene> = Arc::new(move |_: f64, _: f64| radiance_factor);
    let mut sim = SimInstrument::new(
        SamplePort::new(scene),
        SimConfig {
            seed,
            ..SimConfig::default()
        },
    );
    let hardware = sim.hardware_mut();
    hardware.set_lamp(true);
    hardware.select_range(before);
    hardware.advance_to(100_000);
    hardware.drain_samples(&mut |_| {}).expect("no loss");
    hardware.select_range(after);
    hardware.advance_to(130_000);
    let mut blocks = Vec::new();
    hardware
        .drain_samples(&mut |s| blocks.push(f64::from(s.counts)))
        .expect("no loss");
    let detector = hardware.detector();
    // At (30°, 30°), where the arms stand at power-up.
    let settled = detector.dark_offset_counts()
        + detector.signal_counts(
            radiance_factor,
            30.0,
            usize::from(after),
            detector.lamp_output(0.115),
        );
    (blocks, settled)
}

#[test]
fn blocks_within_a_ranges_settling_time_are_wrong_and_those_the_firmware_keeps_are_not() {
    // Levels read mid-scale on the range switched to, from each neighbour.
    for (before, after, radiance_factor) in
        [(0u8, 1u8, 10.0), (1, 2, 100.0), (2, 1, 10.0), (1, 0, 1.0)]
    {
        let range = CONFIG.detector_ranges[usize::from(after)];
        // The firmware drops the block the switch falls in and ⌈settle / block⌉ more.
        let blanked = 1 + range.settle_us.div_ceil(CONFIG.detector_block_us) as usize;
        let (mut worst_kept, mut least_first) = (0f64, f64::MAX);
        for seed in 0..SEEDS {
            let (blocks, settled) = blocks_after_a_switch(radiance_factor, before, after, seed);
            let sim = SimInstrument::new(
                SamplePort::new(Arc::new(|_: f64, _: f64| 0.0)),
                SimConfig::default(),
            );
            let sigma = sim.hardware().detector().sample_sigma_counts(settled);
            least_first = least_first.min((blocks[0] - settled).abs() / sigma);
            // The first block after the switch is wrong by far more than its noise.
            assert!(
                (blocks[0] - settled).abs() > 6.0 * sigma,
                "{before} → {after}: first block {} vs settled {settled:.0} (σ {sigma:.0})",
                blocks[0]
            );
            for &block in &blocks[blanked..] {
                worst_kept = worst_kept.max((block - settled).abs() / sigma);
            }
        }
        eprintln!(
            "{before} → {after}: {blanked} blocks blanked, the first block off by {:.1} σ or more, the worst kept block {worst_kept:.2} σ off",
            least_first
        );
        assert!(
            worst_kept < 5.0,
            "{before} → {after}: a kept block {worst_kept} σ off"
        );
    }
}

#[test]
fn a_scene_beyond_the_least_sensitive_ranges_full_scale_gives_saturated_bins_never_clipped_unflagged()
 {
    // A peak that passes range 2's full scale near its top (radiance factor 400 at θi 45°:
    // 1.2 × full scale there), on a diffuse level read on range 0, and a scene beyond it
    // everywhere.
    let scenes: [(Arc<dyn Scene>, &str); 2] = [
        (peak(0.8, 400.0, 45.0, 1.6), "peak"),
        (Arc::new(|_: f64, _: f64| 1000.0), "everywhere"),
    ];
    for (scene, name) in scenes {
        let mut saturated = 0;
        for seed in 0..SEEDS / 2 {
            let mut host = Host::ready(scene.clone(), 400 + seed, 1.0);
            let s = sweep(6, 45.0, 30.0, 60.0, 60.0, 8, None);
            let (_, bins) = host.sweep(s);
            for bin in bins.iter().filter(|b| b.flags & SweepBin::EMPTY == 0) {
                // Unclipped, what the interval would read.
                let expected = host.expected_counts(scene.as_ref(), &s, bin);
                if bin.flags & SweepBin::SATURATED != 0 {
                    saturated += 1;
                    assert_eq!(
                        bin.range, 2,
                        "{name}: saturated only where no range is left: {bin:?}"
                    );
                    assert!(
                        f64::from(bin.mean_counts) >= 0.98 * FULL_SCALE,
                        "{name}: {bin:?}"
                    );
                } else {
                    assert!(
                        expected < FULL_SCALE,
                        "{name} seed {seed}: a bin beyond full scale unflagged: {bin:?}, expected {expected:.0}"
                    );
                    host.check_value(scene.as_ref(), &s, bin, &format!("{name} seed {seed}"));
                }
            }
            if name == "everywhere" {
                assert!(
                    bins.iter().all(|b| b.flags & SweepBin::SATURATED != 0),
                    "{name}: every bin saturated"
                );
            }
        }
        assert!(saturated > 0, "{name}: some bins saturate");
    }
}

#[test]
fn the_same_seed_gives_the_same_bins_and_another_seed_other_noise() {
    let scene = peak(0.5, 20.0, 40.0, 1.5);
    let s = sweep(7, 40.0, 30.0, 50.0, 30.0, 8, None);
    let run = |seed| Host::ready(scene.clone(), seed, 1.0).sweep(s).1;
    let (a, b, c) = (run(9), run(9), run(10));
    assert_eq!(a, b);
    assert_ne!(
        a.iter().map(|b| b.mean_counts).collect::<Vec<_>>(),
        c.iter().map(|b| b.mean_counts).collect::<Vec<_>>()
    );
}

/// A sweep the device accepts at θi = 40°: from and to in 0…85° clear of the guard, a
/// speed, a bin from the shortest up to a tenth of the travel, at most ~1.2 s of travel.
fn valid_sweep() -> impl Strategy<Value = Sweep> {
    (
        0i32..=6800,
        80i32..=4000,
        any::<bool>(),
        500u32..=60_000,
        0.0f64..1.0,
        proptest::option::of(0u8..3),
    )
        .prop_map(|(from, length, forwards, speed, bin_fraction, range)| {
            let to = if forwards {
                (from + length).min(6800)
            } else {
                (from - length).max(0)
            };
            let travel = (to - from).unsigned_abs();
            let shortest = firmware::sweep::min_bin_ticks(&CONFIG, speed);
            let longest = (travel / 10).max(shortest);
            let bin_ticks = (shortest + ((longest - shortest) as f64 * bin_fraction) as u32) as u16;
            Sweep {
                sweep_id: 8,
                theta_i: Angle::from_whole_deg(40),
                from: Angle::from_ticks(from),
                to: Angle::from_ticks(to),
                speed_mdeg_per_s: speed,
                bin_ticks,
                range,
                target: Target::Sample,
            }
        })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

    #[test]
    fn bins_tile_the_sweep_and_each_interval_is_the_arms_step_counts(s in valid_sweep(), seed in 0u64..1000) {
        prop_assume!(firmware::sweep::check_sweep(&CONFIG, &s).is_ok());
        let mut host = Host::ready(peak(0.5, 30.0, 40.0, 1.6), seed, 1.0);
        let (plan, bins) = host.sweep(s);
        prop_assert_eq!(bins.len(), usize::from(plan.bins));
        prop_assert_eq!(bins[0].start, s.from);
        prop_assert_eq!(bins.last().unwrap().end, s.to);
        let arm = &host.sim.hardware().mechanics().arms[1];
        for (k, bin) in bins.iter().enumerate() {
            prop_assert_eq!(usize::from(bin.index), k);
            if k > 0 {
                prop_assert_eq!(bin.start, bins[k - 1].end);
            }
            // Closed by the block that ended at the poll that sent it: the step count then.
            prop_assert_eq!(bin.end.ticks(), arm.steps_at(bin.device_time_us), "{:?}", bin);
            // And not before the bin's nominal end (towards `to`).
            let direction = (s.to.ticks() - s.from.ticks()).signum();
            let nominal = if k + 1 == bins.len() { s.to.ticks() } else { s.from.ticks() + direction * (k as i32 + 1) * i32::from(s.bin_ticks) };
            prop_assert!(direction * (bin.end.ticks() - nominal) >= 0, "{:?} before its nominal end {}", bin, nominal);
        }
    }
}
