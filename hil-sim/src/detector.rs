//! The detector as the instrument has it (INSTRUMENT.md), and nothing more: angular
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
    /// ADC sample rate, per second (sets the sample count of a reading).
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
            sample_rate_hz: 10_000.0,
            noise_scale: 1.0,
        }
    }
}

/// Statistics of one integration, before the firmware's auto-ranging looks at it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RawReading {
    /// Mean counts, clipped at full scale.
    pub mean_counts: f64,
    /// Standard deviation of the samples, counts.
    pub std_counts: f64,
    /// Number of samples.
    pub samples: u32,
    /// The signal reached full scale.
    pub saturated: bool,
}

/// Points of the acceptance quadrature (midpoint rule over the full width). 16 points
/// resolve a 0.8° glossy lobe seen through a 1° window to better than 1e-4 relative.
const ACCEPTANCE_POINTS: usize = 16;

/// The simulated detector with its noise generator.
pub struct Detector {
    params: DetectorParams,
    rng: ChaCha12Rng,
    /// +1 or −1: which way this lamp drifts.
    drift_sign: f64,
    /// Counts per unit radiance factor per unit cos θi on the most sensitive range.
    counts_per_unit: f64,
}

impl Detector {
    /// A detector whose noise comes from `seed`.
    pub fn new(params: DetectorParams, seed: u64) -> Detector {
        let mut rng = ChaCha12Rng::seed_from_u64(seed);
        let drift_sign = if rng.random::<bool>() { 1.0 } else { -1.0 };
        let white = crate::scene::WHITE_TILE_RADIANCE_FACTOR * 20f64.to_radians().cos();
        let counts_per_unit = params.white_fraction_at_20deg * params.full_scale_counts / white;
        Detector { params, rng, drift_sign, counts_per_unit }
    }

    /// The parameters.
    pub fn params(&self) -> &DetectorParams {
        &self.params
    }

    /// The scene's radiance factor as the detector sees it: averaged over the acceptance
    /// window in θr (the arms move in one plane, so the window is in-plane).
    pub fn seen_radiance_factor(&self, scene: &dyn Scene, theta_i_deg: f64, theta_r_deg: f64) -> f64 {
        let width = self.params.acceptance_deg;
        if width <= 0.0 {
            return scene.radiance_factor(theta_i_deg, theta_r_deg);
        }
        let step = width / ACCEPTANCE_POINTS as f64;
        let sum: f64 = (0..ACCEPTANCE_POINTS)
            .map(|k| theta_r_deg - width / 2.0 + (k as f64 + 0.5) * step)
            .map(|theta_r| scene.radiance_factor(theta_i_deg, theta_r))
            .sum();
        sum / ACCEPTANCE_POINTS as f64
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
    pub fn signal_counts(&self, radiance_factor: f64, theta_i_deg: f64, range: usize, lamp: f64) -> f64 {
        let gain = self.params.relative_gains.get(range).copied().unwrap_or(0.0);
        self.counts_per_unit * radiance_factor * theta_i_deg.to_radians().cos().max(0.0) * lamp * gain
    }

    /// One integration: `signal_counts` above dark (0 with the lamp off) on the ADC.
    pub fn integrate(&mut self, signal_counts: f64, integration_ms: u16) -> RawReading {
        let p = &self.params;
        let full_scale = p.full_scale_counts;
        let time_factor = (100.0 / f64::from(integration_ms.max(1))).sqrt();
        let read_sigma = p.read_noise_fraction * full_scale;
        let at_40 = 0.4 * full_scale;
        let shot_sigma = p.shot_noise_fraction_at_40pct * at_40 * (signal_counts.max(0.0) / at_40).sqrt();
        let sigma_mean = p.noise_scale * time_factor * (read_sigma * read_sigma + shot_sigma * shot_sigma).sqrt();
        let truth = signal_counts + self.dark_offset_counts();
        let noise: f64 = self.rng.sample(StandardNormal);
        let samples = ((p.sample_rate_hz * f64::from(integration_ms) / 1000.0).round() as u32).max(1);
        let mean = truth + sigma_mean * noise;
        let saturated = truth >= full_scale;
        RawReading {
            mean_counts: mean.clamp(0.0, full_scale),
            // Samples are independent, so their spread is √n times the mean's.
            std_counts: if saturated { 0.0 } else { sigma_mean * f64::from(samples).sqrt() },
            samples,
            saturated,
        }
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

    #[test]
    fn same_seed_same_noise_and_noise_falls_with_time() {
        let mut a = Detector::new(DetectorParams::default(), 7);
        let mut b = Detector::new(DetectorParams::default(), 7);
        for _ in 0..10 {
            assert_eq!(a.integrate(20_000.0, 100), b.integrate(20_000.0, 100));
        }
        let short = a.integrate(20_000.0, 25).std_counts / f64::from(a.integrate(20_000.0, 25).samples).sqrt();
        let long = a.integrate(20_000.0, 400).std_counts / f64::from(a.integrate(20_000.0, 400).samples).sqrt();
        assert!((short / long - 4.0).abs() < 1e-9, "σ of the mean ∝ 1/√T: {short} vs {long}");
    }
}
