//! The detector as the instrument has it (the reference instrument), and nothing more: angular
//! response ([`Response`]: a top-hat acceptance by default), dark offset, shot and read noise
//! that fall with integration time, lamp drift, range gains and saturation, all drawn from a
//! seeded generator so that a run repeats exactly.
//!
//! A mirror on the port (a scene with [`Scene::mirror_index`], the black glass standard) is
//! not a radiance factor at a point: its reflected beam is as narrow as the lamp's, so what
//! the detector reads of it is the detector's own angular response, centred on specular
//! ([`Detector::seen_radiance_factor`]).

use crate::scene::{Scene, fresnel_unpolarized};
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
    /// Angular response in θr (the reference instrument's: a 1° top-hat; a width of 0 is an
    /// ideal point detector).
    pub response: Response,
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
            response: Response::TopHat { width_deg: 1.0 },
            read_noise_fraction: 2e-4,
            shot_noise_fraction_at_40pct: 1e-3,
            dark_offset_fraction: 3e-3,
            lamp_drift_per_hour: 2e-3,
            sample_rate_hz: 1_000.0,
            noise_scale: 1.0,
        }
    }
}

/// Widest response the simulator takes, degrees (a top-hat's width, a Gaussian's FWHM, a
/// trapezoid's base): the acceptance's own limit on the command line.
pub const MAX_RESPONSE_WIDTH_DEG: f64 = 10.0;

/// The mirror's peak scale, degrees: the instrument's out-of-plane factor.
///
/// A mirror sends a Fresnel fraction of the lamp's beam into a cone as narrow as the beam,
/// so in the plane of the arms the detector reads it through its own angular response: the
/// reading's profile in θr is that fraction × the response's density (per degree). How high
/// that profile stands, as a radiance factor against the white tile, depends on what the
/// plane does not show: how much of the beam's cross-section the aperture takes in out of
/// the plane, against the tile's cosine-law radiance into it. This constant stands for all
/// of that on this instrument. One radian in degrees: with a 1° top-hat the black glass
/// standard's peak at θi = 20° is a radiance factor of about 3, at 75° about 59 and at 85°
/// about 410, all below the least sensitive range's full scale (the last at a sixth of it).
/// The host never needs it: a characterization normalizes a measured mirror peak by its own
/// area.
pub const MIRROR_SCALE_DEG: f64 = 180.0 / std::f64::consts::PI;

/// σ of a Gaussian of unit FWHM: 1 / (2·√(2 ln 2)).
const SIGMA_PER_FWHM: f64 = 0.424_660_900_144_009_5;

/// A Gaussian response is integrated over ±this many σ (the mass beyond: 1.2e-15), in
/// [`GAUSSIAN_PANELS`] equal panels of Gauss–Legendre each.
const GAUSSIAN_SPAN_SIGMAS: f64 = 8.0;

/// Panels of the Gaussian response's quadrature: 2σ each, on which the 16-point rule
/// integrates the density times a smooth scene to far below 1e-9 (the test below).
const GAUSSIAN_PANELS: usize = 8;

/// The detector's angular response in θr: the weight with which it sees the scene at an
/// offset u from the angle it stands at. Full widths in degrees, centred on 0; a width of 0
/// is an ideal point detector.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Response {
    /// Uniform over a full width: an aperture imaged sharply (the reference instrument's
    /// declared acceptance).
    TopHat {
        /// Full width, degrees.
        width_deg: f64,
    },
    /// A Gaussian: an aperture seen through a blurring lens, or a lamp's soft beam.
    Gaussian {
        /// Full width at half maximum, degrees.
        fwhm_deg: f64,
    },
    /// A flat top with linear flanks: a sharp aperture seen by a beam of its own width.
    Trapezoid {
        /// Full width of the flat top, degrees (≤ `base_deg`; 0: a triangle).
        top_deg: f64,
        /// Full width at the base, where the flanks reach 0, degrees.
        base_deg: f64,
    },
}

/// A response the simulator cannot take.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ResponseError {
    /// A width not finite, negative or too wide.
    #[error("a response's widths must be in [0, {MAX_RESPONSE_WIDTH_DEG}] degrees, got {0}")]
    Width(f64),
    /// A trapezoid whose top is wider than its base.
    #[error("a trapezoid's top ({top_deg}°) must not be wider than its base ({base_deg}°)")]
    TopWiderThanBase {
        /// The top's width.
        top_deg: f64,
        /// The base's width.
        base_deg: f64,
    },
}

impl Response {
    /// An ideal point detector.
    pub const POINT: Response = Response::TopHat { width_deg: 0.0 };

    /// Whether the simulator takes it: every width finite and in [0,
    /// [`MAX_RESPONSE_WIDTH_DEG`]], a trapezoid's top no wider than its base.
    pub fn validate(&self) -> Result<(), ResponseError> {
        let widths = match *self {
            Response::TopHat { width_deg } => [width_deg, 0.0],
            Response::Gaussian { fwhm_deg } => [fwhm_deg, 0.0],
            Response::Trapezoid { top_deg, base_deg } => [top_deg, base_deg],
        };
        if let Some(&bad) = widths
            .iter()
            .find(|w| !(w.is_finite() && (0.0..=MAX_RESPONSE_WIDTH_DEG).contains(*w)))
        {
            return Err(ResponseError::Width(bad));
        }
        if let Response::Trapezoid { top_deg, base_deg } = *self {
            if top_deg > base_deg {
                return Err(ResponseError::TopWiderThanBase { top_deg, base_deg });
            }
        }
        Ok(())
    }

    /// Full width at half maximum, degrees (a trapezoid's: the mean of top and base).
    pub fn fwhm_deg(&self) -> f64 {
        match *self {
            Response::TopHat { width_deg } => width_deg,
            Response::Gaussian { fwhm_deg } => fwhm_deg,
            Response::Trapezoid { top_deg, base_deg } => 0.5 * (top_deg + base_deg),
        }
    }

    /// Whether it is an ideal point detector (no width): it has no density, and sees a
    /// point function at the very angle it stands at.
    pub fn is_point(&self) -> bool {
        // A NaN width is no width either.
        self.fwhm_deg().is_nan() || self.fwhm_deg() <= 0.0
    }

    /// Variance of the response about its centre, degrees². A trapezoid is the convolution
    /// of two uniforms of widths (base ± top)/2, whose variances add.
    pub fn variance_deg2(&self) -> f64 {
        match *self {
            Response::TopHat { width_deg } => width_deg * width_deg / 12.0,
            Response::Gaussian { fwhm_deg } => (fwhm_deg * SIGMA_PER_FWHM).powi(2),
            Response::Trapezoid { top_deg, base_deg } => {
                let (wide, narrow) = (0.5 * (base_deg + top_deg), 0.5 * (base_deg - top_deg));
                (wide * wide + narrow * narrow) / 12.0
            }
        }
    }

    /// The response's density at offset `u_deg` from its centre, per degree: ∫ density du
    /// = 1. A top-hat's edge reads half its height (the mean of its two sides). A point
    /// detector has no density (its weight is all at 0): 0 everywhere.
    pub fn density(&self, u_deg: f64) -> f64 {
        if self.is_point() {
            return 0.0;
        }
        let u = u_deg.abs();
        match *self {
            Response::TopHat { width_deg } => top_hat_density(width_deg, u),
            Response::Gaussian { fwhm_deg } => {
                let sigma = fwhm_deg * SIGMA_PER_FWHM;
                (-0.5 * (u / sigma).powi(2)).exp() / (sigma * (2.0 * std::f64::consts::PI).sqrt())
            }
            Response::Trapezoid { top_deg, base_deg } => {
                if top_deg >= base_deg {
                    return top_hat_density(base_deg, u);
                }
                let height = 2.0 / (top_deg + base_deg);
                if u <= 0.5 * top_deg {
                    height
                } else if u < 0.5 * base_deg {
                    height * (0.5 * base_deg - u) / (0.5 * (base_deg - top_deg))
                } else {
                    0.0
                }
            }
        }
    }

    /// The response's cumulative distribution: its weight at offsets below `u_deg`. A point
    /// detector's is a step (½ at 0).
    pub fn cdf(&self, u_deg: f64) -> f64 {
        if u_deg.is_nan() {
            return f64::NAN;
        }
        if self.is_point() {
            return if u_deg < 0.0 {
                0.0
            } else if u_deg > 0.0 {
                1.0
            } else {
                0.5
            };
        }
        // The weight below −|u| (the left tail), then by symmetry.
        let u = u_deg.abs();
        let tail = match *self {
            Response::TopHat { width_deg } => (0.5 - u / width_deg).max(0.0),
            Response::Gaussian { fwhm_deg } => {
                0.5 * erfc_nonnegative(u / (fwhm_deg * SIGMA_PER_FWHM * std::f64::consts::SQRT_2))
            }
            Response::Trapezoid { top_deg, base_deg } => {
                if top_deg >= base_deg {
                    (0.5 - u / base_deg).max(0.0)
                } else {
                    let height = 2.0 / (top_deg + base_deg);
                    let flank = 0.5 * (base_deg - top_deg);
                    if u >= 0.5 * base_deg {
                        0.0
                    } else if u >= 0.5 * top_deg {
                        // The flank's triangle beyond u.
                        let beyond = 0.5 * base_deg - u;
                        0.5 * height * beyond * beyond / flank
                    } else {
                        0.5 * height * flank + height * (0.5 * top_deg - u)
                    }
                }
            }
        };
        if u_deg < 0.0 { tail } else { 1.0 - tail }
    }

    /// The response's mean density over offsets [a, b] (either order), per degree:
    /// (cdf(b) − cdf(a)) / (b − a), the density itself where a = b. What a detector that
    /// swept evenly across a mirror's beam over that travel reads of it, per unit of peak.
    pub fn mean_density(&self, a_deg: f64, b_deg: f64) -> f64 {
        if a_deg == b_deg {
            return self.density(a_deg);
        }
        (self.cdf(b_deg) - self.cdf(a_deg)) / (b_deg - a_deg)
    }

    /// The stretches of offset on which the density is smooth (linear or Gaussian), as the
    /// quadrature takes them, degrees.
    fn smooth_pieces(&self) -> Vec<(f64, f64)> {
        let pieces = match *self {
            Response::TopHat { width_deg } => vec![(-0.5 * width_deg, 0.5 * width_deg)],
            Response::Gaussian { fwhm_deg } => {
                let reach = GAUSSIAN_SPAN_SIGMAS * fwhm_deg * SIGMA_PER_FWHM;
                let panel = 2.0 * reach / GAUSSIAN_PANELS as f64;
                (0..GAUSSIAN_PANELS)
                    .map(|k| (-reach + k as f64 * panel, -reach + (k + 1) as f64 * panel))
                    .collect()
            }
            Response::Trapezoid { top_deg, base_deg } => vec![
                (-0.5 * base_deg, -0.5 * top_deg),
                (-0.5 * top_deg, 0.5 * top_deg),
                (0.5 * top_deg, 0.5 * base_deg),
            ],
        };
        pieces.into_iter().filter(|(a, b)| b > a).collect()
    }

    /// Offsets (degrees) and weights (summing to 1) that average a smooth scene through the
    /// response: `rule` (Gauss–Legendre on (−1, 1)) on each smooth piece, weighted by the
    /// density. Empty for a point detector.
    fn quadrature(&self, rule: &[(f64, f64)]) -> Vec<(f64, f64)> {
        if self.is_point() {
            return Vec::new();
        }
        let mut nodes: Vec<(f64, f64)> = self
            .smooth_pieces()
            .into_iter()
            .flat_map(|(a, b)| {
                let (centre, half) = (0.5 * (a + b), 0.5 * (b - a));
                rule.iter()
                    .map(move |&(x, w)| (centre + half * x, w * half))
            })
            .map(|(u, w)| (u, w * self.density(u)))
            .collect();
        // Divided by the weights' own sum (1 up to rounding and the Gaussian's far tails), so
        // that a scene the same across the response is seen as itself.
        let total: f64 = nodes.iter().map(|&(_, w)| w).sum();
        for node in &mut nodes {
            node.1 /= total;
        }
        nodes
    }
}

/// Offsets this close to a top-hat's edge are on it, degrees: angles on the arms' tick grid
/// carry rounding in their difference (20.15° − 20° is 0.149999…), and an edge on the grid
/// must read as the edge whichever way the rounding went, or a response of whole ticks
/// would be seen a tick wider or narrower than it is.
const EDGE_TOLERANCE_DEG: f64 = 1e-9;

/// A top-hat's density at |u| = `u_abs`: its edge half its height.
fn top_hat_density(width_deg: f64, u_abs: f64) -> f64 {
    let from_edge = u_abs - 0.5 * width_deg;
    if from_edge.abs() <= EDGE_TOLERANCE_DEG {
        0.5 / width_deg
    } else if from_edge < 0.0 {
        1.0 / width_deg
    } else {
        0.0
    }
}

/// erfc(x) for x ≥ 0, to about 1e-15 relative up to x = 3 and better beyond: below 3 as
/// 1 − erf(x), erf by its series of positive terms (2/√π)·e^(−x²)·Σ (2x²)ⁿ·x / (1·3·…·(2n+1))
/// (no cancellation); from 3 on by the continued fraction of Laplace, evaluated from its
/// tail (60 levels: converged to rounding at x = 3).
fn erfc_nonnegative(x: f64) -> f64 {
    let two_over_sqrt_pi = std::f64::consts::FRAC_2_SQRT_PI;
    if x < 3.0 {
        let (mut term, mut sum) = (x, x);
        let twice_square = 2.0 * x * x;
        for n in 1..200 {
            term *= twice_square / (2 * n + 1) as f64;
            sum += term;
            if term <= 1e-17 * sum {
                break;
            }
        }
        1.0 - two_over_sqrt_pi * (-x * x).exp() * sum
    } else {
        // erfc(x) = e^(−x²)/√π · 1/(x + (1/2)/(x + 1/(x + (3/2)/(x + …)))).
        let mut fraction = x;
        for k in (1..=60).rev() {
            fraction = x + 0.5 * k as f64 / fraction;
        }
        0.5 * two_over_sqrt_pi * (-x * x).exp() / fraction
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
    /// The quadrature of a response other than a top-hat: offsets (degrees) and weights
    /// summing to 1 (a top-hat keeps the acceptance rule's own code path, to the bit).
    response_rule: Vec<(f64, f64)>,
}

impl Detector {
    /// A detector whose noise comes from `seed`.
    pub fn new(params: DetectorParams, seed: u64) -> Detector {
        let mut rng = ChaCha12Rng::seed_from_u64(seed);
        let drift_sign = if rng.random::<bool>() { 1.0 } else { -1.0 };
        let white = crate::scene::WHITE_TILE_RADIANCE_FACTOR * 20f64.to_radians().cos();
        let counts_per_unit = params.white_fraction_at_20deg * params.full_scale_counts / white;
        let acceptance_rule = gauss_legendre(ACCEPTANCE_POINTS);
        let response_rule = match params.response {
            Response::TopHat { .. } => Vec::new(),
            other => other.quadrature(&acceptance_rule),
        };
        Detector {
            params,
            rng,
            drift_sign,
            counts_per_unit,
            acceptance_rule,
            response_rule,
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

    /// The scene's radiance factor as the detector sees it: averaged through the response
    /// in θr (the arms move in one plane, so the response is in-plane), plus a mirror's
    /// reflected beam where the scene is one ([`Detector::mirror_radiance_factor`]).
    pub fn seen_radiance_factor(
        &self,
        scene: &dyn Scene,
        theta_i_deg: f64,
        theta_r_deg: f64,
    ) -> f64 {
        let seen = self.seen_point_function(scene, theta_i_deg, theta_r_deg);
        match scene.mirror_index() {
            None => seen,
            Some(n) => seen + self.mirror_radiance_factor(n, theta_i_deg, theta_r_deg),
        }
    }

    /// What the detector standing at `theta_r_deg` reads of a mirror of refractive index
    /// `n` lit at `theta_i_deg`, as a radiance factor: the mirror's unpolarized Fresnel
    /// reflectance × the response's density at θr − θi × [`MIRROR_SCALE_DEG`], over cos θi
    /// (the reflected power does not fall with cos θi as the tile's radiance does). A point
    /// detector reads 0: it meets a beam of no width at one angle only, a set of no measure.
    pub fn mirror_radiance_factor(&self, n: f64, theta_i_deg: f64, theta_r_deg: f64) -> f64 {
        let cos_i = theta_i_deg.to_radians().cos();
        if cos_i.is_nan() || cos_i <= 0.0 {
            return 0.0;
        }
        fresnel_unpolarized(n, theta_i_deg)
            * self.params.response.density(theta_r_deg - theta_i_deg)
            * MIRROR_SCALE_DEG
            / cos_i
    }

    /// The scene's point function averaged through the response.
    fn seen_point_function(&self, scene: &dyn Scene, theta_i_deg: f64, theta_r_deg: f64) -> f64 {
        let width = match self.params.response {
            Response::TopHat { width_deg } => width_deg,
            _ if self.response_rule.is_empty() => {
                return scene.radiance_factor(theta_i_deg, theta_r_deg);
            }
            _ => {
                return self
                    .response_rule
                    .iter()
                    .map(|&(u, w)| w * scene.radiance_factor(theta_i_deg, theta_r_deg + u))
                    .sum();
            }
        };
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

    /// The lamp's drift, fraction per hour of device time, with the sign drawn for this
    /// instrument.
    pub fn lamp_drift_per_hour(&self) -> f64 {
        self.drift_sign * self.params.lamp_drift_per_hour
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

    /// The shapes the tests below take: narrow and wide, a triangle and a near top-hat.
    const SHAPES: [Response; 8] = [
        Response::TopHat { width_deg: 0.3 },
        Response::TopHat { width_deg: 1.0 },
        Response::Gaussian { fwhm_deg: 0.3 },
        Response::Gaussian { fwhm_deg: 3.0 },
        Response::Trapezoid {
            top_deg: 0.1,
            base_deg: 0.5,
        },
        Response::Trapezoid {
            top_deg: 0.0,
            base_deg: 2.0,
        },
        Response::Trapezoid {
            top_deg: 1.2,
            base_deg: 1.8,
        },
        Response::Trapezoid {
            top_deg: 0.7,
            base_deg: 0.7,
        },
    ];

    /// Beyond this offset a shape's density is 0 (a Gaussian's: below 1e-15 of its mass).
    fn reach_deg(response: &Response) -> f64 {
        match *response {
            Response::TopHat { width_deg } => 0.5 * width_deg,
            Response::Gaussian { fwhm_deg } => 8.0 * fwhm_deg * SIGMA_PER_FWHM,
            Response::Trapezoid { base_deg, .. } => 0.5 * base_deg,
        }
    }

    /// Σ f(u)·du by the midpoint rule on `n` cells over [−reach, reach].
    fn dense_integral(reach: f64, n: usize, f: impl Fn(f64) -> f64) -> f64 {
        let du = 2.0 * reach / n as f64;
        (0..n).map(|k| f(-reach + (k as f64 + 0.5) * du) * du).sum()
    }

    #[test]
    fn every_response_integrates_to_one_with_its_stated_fwhm_variance_and_cdf() {
        for r in SHAPES {
            r.validate().unwrap();
            let reach = reach_deg(&r) * 1.01;
            let n = 400_000;
            let mass = dense_integral(reach, n, |u| r.density(u));
            assert!((mass - 1.0).abs() < 1e-5, "{r:?}: mass {mass}");
            let variance = dense_integral(reach, n, |u| u * u * r.density(u));
            assert!(
                (variance / r.variance_deg2() - 1.0).abs() < 1e-5,
                "{r:?}: variance {variance} vs {}",
                r.variance_deg2()
            );
            // Half the peak at ±FWHM/2 (a top-hat's edge reads the mean of its sides).
            let (peak, half) = (r.density(0.0), 0.5 * r.fwhm_deg());
            for u in [-half, half] {
                assert!(
                    (r.density(u) / peak - 0.5).abs() < 1e-12,
                    "{r:?}: density at {u} is {} of the peak",
                    r.density(u) / peak
                );
            }
            // The cdf is the density's integral, 0 and 1 beyond the reach, ½ at the centre.
            assert!(r.cdf(-reach * 2.0) < 1e-15, "{r:?}");
            assert_eq!(r.cdf(reach * 2.0), 1.0, "{r:?}");
            assert!((r.cdf(0.0) - 0.5).abs() < 1e-15, "{r:?}");
            for fraction in [-0.9, -0.6, -0.3, -0.05, 0.2, 0.45, 0.8] {
                let u = fraction * reach;
                let below = dense_integral(reach, n, |v| if v < u { r.density(v) } else { 0.0 });
                assert!(
                    (r.cdf(u) - below).abs() < 2e-5,
                    "{r:?}: cdf({u}) {} vs {below}",
                    r.cdf(u)
                );
            }
            // The mean density over a travel is the cdf's difference over it.
            let (a, b) = (-0.37 * reach, 0.21 * reach);
            let mean = dense_integral(reach, n, |v| {
                if (a..b).contains(&v) {
                    r.density(v)
                } else {
                    0.0
                }
            }) / (b - a);
            assert!(
                (r.mean_density(a, b) - mean).abs() < 1e-4 * r.density(0.0),
                "{r:?}: mean density {} vs {mean}",
                r.mean_density(a, b)
            );
            assert_eq!(r.mean_density(a, a), r.density(a));
        }
        let point = Response::POINT;
        assert!(point.is_point() && Response::Gaussian { fwhm_deg: 0.0 }.is_point());
        assert_eq!(
            (point.density(0.0), point.cdf(-1e-9), point.cdf(1e-9)),
            (0.0, 0.0, 1.0)
        );
    }

    #[test]
    fn bad_responses_are_refused() {
        for bad in [
            Response::TopHat { width_deg: -0.1 },
            Response::Gaussian { fwhm_deg: f64::NAN },
            Response::Gaussian { fwhm_deg: 11.0 },
            Response::Trapezoid {
                top_deg: 0.5,
                base_deg: 0.3,
            },
            Response::Trapezoid {
                top_deg: 0.1,
                base_deg: f64::INFINITY,
            },
        ] {
            assert!(bad.validate().is_err(), "{bad:?}");
        }
    }

    #[test]
    fn erfc_matches_its_tabulated_values_on_both_sides_of_the_switch() {
        for (x, value) in [
            (0.0, 1.0),
            (0.5, 0.479_500_122_186_953_5),
            (1.0, 0.157_299_207_050_285_13),
            (2.0, 0.004_677_734_981_047_265),
            (2.999, 2.223_016_859_983_405_8e-5),
            (3.0, 2.209_049_699_858_543_8e-5),
            (4.0, 1.541_725_790_028_002e-8),
            (5.0, 1.537_459_794_428_035_1e-12),
            (6.0, 2.151_973_671_249_891_6e-17),
        ] {
            let got = erfc_nonnegative(x);
            assert!(
                (got / value - 1.0).abs() < 1e-12,
                "erfc({x}) = {got}, not {value}"
            );
        }
    }

    /// Through a Gaussian or a trapezoid the smooth scenes' average is good to 1e-9: a lobe
    /// as narrow as G's (1.6° in θr) and one half as wide, on its flank and at its top,
    /// against a dense midpoint sum of the density times the scene.
    #[test]
    fn a_shaped_response_averages_a_narrow_lobe_to_1e9() {
        for sd in [1.6, 0.8] {
            let lobe = move |_: f64, theta_r: f64| {
                (-(theta_r - 60.0).powi(2) / (2.0 * sd * sd)).exp() * 50.0 + 0.8
            };
            for r in SHAPES {
                let detector = Detector::new(
                    DetectorParams {
                        response: r,
                        ..DetectorParams::default()
                    },
                    1,
                );
                let reach = reach_deg(&r);
                for theta_r in [60.0, 60.5, 62.0, 63.5, 66.0] {
                    let dense =
                        dense_integral(reach, 400_000, |u| r.density(u) * lobe(60.0, theta_r + u))
                            / dense_integral(reach, 400_000, |u| r.density(u));
                    let seen = detector.seen_radiance_factor(&lobe, 60.0, theta_r);
                    assert!(
                        (seen / dense - 1.0).abs() < 1e-9,
                        "{r:?}, lobe {sd}°, θr {theta_r}: {seen} vs {dense}"
                    );
                }
            }
        }
    }

    /// The black glass: nothing off its beam, its beam the response's density scaled by its
    /// Fresnel reflectance, so that its area in θr (times cos θi over the mirror scale) is
    /// the reflectance whatever the shape; the peak through the default 1° top-hat about 3
    /// at 20° and under the least sensitive range's full scale at 85°.
    #[test]
    fn the_black_glass_reads_the_response_scaled_by_its_fresnel_reflectance() {
        use crate::scene::BlackGlass;
        let glass = BlackGlass::default();
        let at_normal = ((1.567f64 - 1.0) / (1.567 + 1.0)).powi(2);
        assert!((fresnel_unpolarized(1.567, 0.0) - at_normal).abs() < 1e-15);
        assert!((fresnel_unpolarized(1.567, 90.0) - 1.0).abs() < 1e-12);
        // At Brewster's angle the p reflectance vanishes.
        let brewster = 1.567f64.atan().to_degrees();
        let (sin_i, cos_i) = brewster.to_radians().sin_cos();
        let cos_t = (1.0 - (sin_i / 1.567).powi(2)).sqrt();
        let rs = (cos_i - 1.567 * cos_t) / (cos_i + 1.567 * cos_t);
        assert!((fresnel_unpolarized(1.567, brewster) - 0.5 * rs * rs).abs() < 1e-15);

        let reference = Detector::new(DetectorParams::default(), 1);
        let peak_20 = reference.seen_radiance_factor(&glass, 20.0, 20.0);
        assert!((peak_20 - 2.99).abs() < 0.01, "peak at 20°: {peak_20}");
        assert_eq!(reference.seen_radiance_factor(&glass, 20.0, 20.6), 0.0);
        let peak_85 = reference.seen_radiance_factor(&glass, 85.0, 85.0);
        let rail = 65_535.0 - reference.dark_offset_counts();
        assert!(
            reference.signal_counts(peak_85, 85.0, 2, 1.0) < rail,
            "{peak_85}"
        );
        for r in SHAPES {
            let detector = Detector::new(
                DetectorParams {
                    response: r,
                    ..DetectorParams::default()
                },
                1,
            );
            for theta_i in [20.0, 60.0, 75.0] {
                let reach = reach_deg(&r) * 1.01;
                let area = dense_integral(reach, 200_000, |u| {
                    detector.seen_radiance_factor(&glass, theta_i, theta_i + u)
                }) * f64::cos(f64::to_radians(theta_i))
                    / MIRROR_SCALE_DEG;
                let fresnel = fresnel_unpolarized(1.567, theta_i);
                assert!(
                    (area / fresnel - 1.0).abs() < 1e-5,
                    "{r:?} at {theta_i}°: area {area} vs {fresnel}"
                );
            }
        }
        let point = Detector::new(
            DetectorParams {
                response: Response::POINT,
                ..DetectorParams::default()
            },
            1,
        );
        assert_eq!(point.seen_radiance_factor(&glass, 20.0, 20.0), 0.0);
    }

    #[test]
    fn saturation_clips_at_full_scale() {
        let mut detector = Detector::new(DetectorParams::default(), 1);
        assert_eq!(detector.sample(1e9), 65_535);
    }
}
