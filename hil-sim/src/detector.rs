//! The detector as the instrument has it (the reference instrument), and nothing more: angular
//! acceptance, dark offset, shot and read noise that fall with integration time, lamp
//! drift, range gains and saturation, all drawn from a seeded generator so that a run
//! repeats exactly.

use crate::scene::Scene;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha12Rng;
use rand_distr::StandardNormal;

/// Noise and scale of the simulated detector; defaults are the reference instrument's.
#[derive(Clone, Debug, PartialEq)]
pub struct DetectorParams {
    /// ADC counts at full scale.
    pub full_scale_counts: f64,
    /// Gain of each range relative to the most sensitive, most sensitive first.
    pub relative_gains: Vec<f64>,
    /// Fraction of full scale the white tile (0.99) reads at θi = 20°, θr = 0 on the
    /// most sensitive range.
    pub white_fraction_at_20deg: f64,
    /// Detector acceptance, full width, degrees (0 for an ideal point detector).
    pub acceptance_deg: f64,
    /// Read noise of the mean at 100 ms, fraction of full scale.
    pub read_noise_fraction: f64,
    /// Shot noise of the mean at 100 ms, as a fraction of a signal at 40 % of full scale.
    pub shot_noise_fraction_at_40pct: f64,
    /// Dark offset, fraction of full scale (the same on every range: it is the ADC's).
    pub dark_offset_fraction: f64,
    /// Lamp output drift per hour of device time (fraction; sign drawn from the seed).
    pub lamp_drift_per_hour: f64,
    /// ADC sample rate. It sets the sample count of a reading; the noise of a reading's
    /// mean is the stated one whatever the rate (the per-sample noise is scaled to it).
    pub sample_rate_hz: f64,
    /// Multiplies every noise term (1 = the reference instrument; 0 = noiseless).
    pub noise_scale: f64,
}

impl Default for DetectorParams {
    fn default() -> Self {
        DetectorParams {
            full_scale_counts: 65_535.0,
            relative_gains: vec![1.0, 0.1, 0.01],
            white_fraction_at_20deg: 0.40,
            acceptance_deg: 1.0,
            read_noise_fraction: 2e-4,
            shot_noise_fraction_at_40pct: 1e-3,
            dark_offset_fraction: 3e-3,
            lamp_drift_per_hour: 2e-3,
            sample_rate_hz: 1_000.0,
            noise_scale: 1.0,
        }
    }
}

/// Points of the acceptance quadrature: Gauss–Legendre over the full width. The window
/// average of a smooth scene is then exact to far below the noise (G's 0.8° lobe through a
/// 1° window: better than 1e-12 relative), where a 16-point midpoint rule erred by 2e-4.
const ACCEPTANCE_POINTS: usize = 16;

/// Nodes in (−1, 1) and weights of the `n`-point Gauss–Legendre rule, by Newton's method on
/// the Legendre polynomial from the Chebyshev guesses (converges in a few steps to full
/// precision for the small n used here).
fn gauss_legendre(n: usize) -> Vec<(f64, f64)> {
    (0..n)
        .map(|i| {
            let mut x = (std::f64::consts::PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
            let mut derivative = 1.0;
            for _ in 0..100 {
                // P_n(x) and P_{n−1}(x) by the three-term recurrence.
                let (mut p, mut p_prev) = (1.0, 0.0);
                for k in 1..=n {
                    let k = k as f64;
                    (p, p_prev) = (((2.0 * k - 1.0) * x * p - (k - 1.0) * p_prev) / k, p);
                }
                derivative = n as f64 * (x * p - p_prev) / (x * x - 1.0);
                let step = p / derivative;
                x -= step;
                if step.abs() < 1e-16 {
                    break;
                }
            }
            (x, 2.0 / ((1.0 - x * x) * derivative * derivative))
        })
        .collect()
}

/// The simulated detector with its noise generator.
pub struct Detector {
    params: DetectorParams,
    rng: ChaCha12Rng,
    /// +1 or −1: which way this lamp drifts.
    drift_sign: f64,
    /// Counts per unit radiance factor per unit cos θi on the most sensitive range.
    counts_per_unit: f64,
    /// The acceptance quadrature: nodes in (−1, 1) and weights.
    acceptance_rule: Vec<(f64, f64)>,
}

impl Detector {
    /// A detector whose noise comes from `seed`.
    pub fn new(params: DetectorParams, seed: u64) -> Detector {
        let mut rng = ChaCha12Rng::seed_from_u64(seed);
        let drift_sign = if rng.random::<bool>() { 1.0 } else { -1.0 };
        let white = crate::scene::WHITE_TILE_RADIANCE_FACTOR * 20f64.to_radians().cos();
        let counts_per_unit = params.white_fraction_at_20deg * params.full_scale_counts / white;
        Detector {
            params,
            rng,
            drift_sign,
            counts_per_unit,
            acceptance_rule: gauss_legendre(ACCEPTANCE_POINTS),
        }
    }

    /// Its noise drawn from `seed` from now on (the drift's direction and every other
    /// property kept): an instrument switched on again does not repeat its noise.
    pub fn reseed_noise(&mut self, seed: u64) {
        self.rng = ChaCha12Rng::seed_from_u64(seed);
    }

    /// The parameters.
    pub fn params(&self) -> &DetectorParams {
        &self.params
    }

    /// The scene's radiance factor as the detector sees it: averaged over the acceptance
    /// window in θr (the arms move in one plane, so the window is in-plane).
    pub fn seen_radiance_factor(
        &self,
        scene: &dyn Scene,
        theta_i_deg: f64,
        theta_r_deg: f64,
    ) -> f64 {
        let width = self.params.acceptance_deg;
        if width <= 0.0 {
            return scene.radiance_factor(theta_i_deg, theta_r_deg);
        }
        let half = width / 2.0;
        // Divided by the weights' own sum (2 up to rounding), so that a scene the same
        // across the window is seen as itself.
        let (sum, weights) =
            self.acceptance_rule
                .iter()
                .fold((0.0, 0.0), |(sum, weights), &(x, w)| {
                    (
                        sum + w * scene.radiance_factor(theta_i_deg, theta_r_deg + half * x),
                        weights + w,
                    )
                });
        sum / weights
    }

    /// Lamp output relative to its calibrated value after `device_s` seconds.
    pub fn lamp_output(&self, device_s: f64) -> f64 {
        1.0 + self.drift_sign * self.params.lamp_drift_per_hour * device_s / 3600.0
    }

    /// Dark offset in counts.
    pub fn dark_offset_counts(&self) -> f64 {
        self.params.dark_offset_fraction * self.params.full_scale_counts
    }

    /// The noiseless signal above dark, in counts, on `range`.
    pub fn signal_counts(
        &self,
        radiance_factor: f64,
        theta_i_deg: f64,
        range: usize,
        lamp: f64,
    ) -> f64 {
        let gain = self
            .params
            .relative_gains
            .get(range)
            .copied()
            .unwrap_or(0.0);
        self.counts_per_unit
            * radiance_factor
            * theta_i_deg.to_radians().cos().max(0.0)
            * lamp
            * gain
    }

    /// Standard deviation of one ADC sample for a signal of `signal_counts` above dark:
    /// chosen so that the mean of the samples over an integration time T has the stated
    /// read and shot noise at 100 ms, falling as 1/√T.
    pub fn sample_sigma_counts(&self, signal_counts: f64) -> f64 {
        let p = &self.params;
        let read = p.read_noise_fraction * p.full_scale_counts;
        let at_40 = 0.4 * p.full_scale_counts;
        let shot = p.shot_noise_fraction_at_40pct * at_40 * (signal_counts.max(0.0) / at_40).sqrt();
        let samples_in_100ms = p.sample_rate_hz * 0.1;
        p.noise_scale * (read * read + shot * shot).sqrt() * samples_in_100ms.sqrt()
    }

    /// One ADC sample: dark offset plus `signal_counts`, with noise, rounded and clipped
    /// to the ADC's range.
    pub fn sample(&mut self, signal_counts: f64) -> u32 {
        let sigma = self.sample_sigma_counts(signal_counts);
        let noise: f64 = self.rng.sample(StandardNormal);
        let counts = self.dark_offset_counts() + signal_counts + sigma * noise;
        counts.round().clamp(0.0, self.params.full_scale_counts) as u32
    }

    /// A sample whose every conversion was at full scale: full scale, without noise (the
    /// noise is drawn all the same, so that the stream of every later sample is the one it
    /// would have been).
    pub fn saturated_sample(&mut self) -> u32 {
        let _: f64 = self.rng.sample(StandardNormal);
        self.params.full_scale_counts as u32
    }

    /// Time between two ADC samples, µs.
    pub fn sample_period_us(&self) -> u64 {
        (1e6 / self.params.sample_rate_hz).round().max(1.0) as u64
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::WhiteTile;

    #[test]
    fn white_tile_reads_forty_percent_at_twenty_degrees() {
        let detector = Detector::new(DetectorParams::default(), 1);
        let seen = detector.seen_radiance_factor(&WhiteTile::default(), 20.0, 0.0);
        let counts = detector.signal_counts(seen, 20.0, 0, 1.0);
        assert!((counts / 65_535.0 - 0.40).abs() < 1e-12);
    }

    #[test]
    fn glossy_peak_needs_the_least_sensitive_range() {
        let detector = Detector::new(DetectorParams::default(), 1);
        // G's peak at θi = 60° is a radiance factor of about 59.
        assert!(detector.signal_counts(59.0, 60.0, 1, 1.0) > 65_535.0);
        assert!(detector.signal_counts(59.0, 60.0, 2, 1.0) < 65_535.0);
    }

    fn mean_and_sigma_of_means(
        detector: &mut Detector,
        signal: f64,
        samples_per_reading: usize,
        readings: usize,
    ) -> (f64, f64) {
        let means: Vec<f64> = (0..readings)
            .map(|_| {
                (0..samples_per_reading)
                    .map(|_| f64::from(detector.sample(signal)))
                    .sum::<f64>()
                    / samples_per_reading as f64
            })
            .collect();
        let mean = means.iter().sum::<f64>() / readings as f64;
        let var = means.iter().map(|m| (m - mean).powi(2)).sum::<f64>() / (readings - 1) as f64;
        (mean, var.sqrt())
    }

    #[test]
    fn same_seed_same_samples() {
        let mut a = Detector::new(DetectorParams::default(), 7);
        let mut b = Detector::new(DetectorParams::default(), 7);
        let mut c = Detector::new(DetectorParams::default(), 8);
        let sa: Vec<u32> = (0..1000).map(|_| a.sample(20_000.0)).collect();
        let sb: Vec<u32> = (0..1000).map(|_| b.sample(20_000.0)).collect();
        let sc: Vec<u32> = (0..1000).map(|_| c.sample(20_000.0)).collect();
        assert_eq!(sa, sb);
        assert_ne!(sa, sc);
    }

    #[test]
    fn noise_of_a_reading_is_the_stated_one_and_falls_with_integration_time() {
        let mut detector = Detector::new(DetectorParams::default(), 3);
        let full_scale: f64 = 65_535.0;
        let signal = 0.4 * full_scale;
        // At 100 ms (100 samples at 1 kHz): read 0.02 % FS and shot 0.1 % of 40 % FS.
        let expected_100 = ((2e-4 * full_scale).powi(2) + (1e-3 * signal).powi(2)).sqrt();
        let (mean, sigma_100) = mean_and_sigma_of_means(&mut detector, signal, 100, 2000);
        assert!(
            (mean - (signal + 0.003 * full_scale)).abs() < 3.0,
            "mean {mean}"
        );
        assert!(
            (sigma_100 / expected_100 - 1.0).abs() < 0.08,
            "σ at 100 ms {sigma_100} vs {expected_100}"
        );
        let (_, sigma_400) = mean_and_sigma_of_means(&mut detector, signal, 400, 2000);
        assert!(
            (sigma_100 / sigma_400 - 2.0).abs() < 0.2,
            "σ ∝ 1/√T: {sigma_100} vs {sigma_400}"
        );
    }

    #[test]
    fn lamp_drifts_by_the_stated_rate_in_a_seeded_direction() {
        let drifts: Vec<f64> = (0..16)
            .map(|seed| Detector::new(DetectorParams::default(), seed).lamp_output(3600.0) - 1.0)
            .collect();
        assert!(
            drifts.iter().all(|d| (d.abs() - 0.002).abs() < 1e-12),
            "{drifts:?}"
        );
        assert!(drifts.iter().any(|d| *d > 0.0) && drifts.iter().any(|d| *d < 0.0));
    }

    #[test]
    fn acceptance_rule_is_gauss_legendre() {
        let rule = gauss_legendre(ACCEPTANCE_POINTS);
        // Exact for polynomials up to degree 2n − 1 over (−1, 1).
        for degree in 0..2 * ACCEPTANCE_POINTS {
            let integral: f64 = rule.iter().map(|&(x, w)| w * x.powi(degree as i32)).sum();
            let exact = if degree % 2 == 1 {
                0.0
            } else {
                2.0 / (degree as f64 + 1.0)
            };
            assert!(
                (integral - exact).abs() < 1e-14,
                "degree {degree}: {integral} vs {exact}"
            );
        }
    }

    #[test]
    fn the_window_average_of_a_narrow_lobe_matches_a_dense_sum() {
        // A lobe as narrow as glossy paper G's (standard deviation 1.6° in θr) seen through
        // the 1° window, on its flank and at its top: against a 20 001-point midpoint sum.
        let detector = Detector::new(DetectorParams::default(), 1);
        let lobe = |_: f64, theta_r: f64| {
            (-(theta_r - 60.0).powi(2) / (2.0 * 1.6f64.powi(2))).exp() * 50.0 + 0.8
        };
        for theta_r in [60.0, 60.5, 62.0, 63.5, 66.0] {
            let n = 20_001;
            let dense: f64 = (0..n)
                .map(|k| lobe(60.0, theta_r - 0.5 + (k as f64 + 0.5) / n as f64))
                .sum::<f64>()
                / n as f64;
            let seen = detector.seen_radiance_factor(&lobe, 60.0, theta_r);
            assert!(
                (seen / dense - 1.0).abs() < 1e-9,
                "θr {theta_r}: {seen} vs {dense}"
            );
        }
    }

    #[test]
    fn saturation_clips_at_full_scale() {
        let mut detector = Detector::new(DetectorParams::default(), 1);
        assert_eq!(detector.sample(1e9), 65_535);
    }
}
