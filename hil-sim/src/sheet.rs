//! A simulated sheet of paper: the simulator's own physics of the scene on the sample
//! port, written from the method's text (Akao et al.) and independent of any fit.
//!
//! One spot of a sheet has the radiance factor (BRDF × π) in the specular plane
//!
//! ```text
//! f(θi, θr) = ρs · F(ψ) · G(θi, θr) / (cos θi · cos θr) · D(θa) + ρd      microfacet part + Lambert
//!           + forward(θi, θr)                                           fibres (off by default)
//!           + bump(θi, θr)                                              narrow rise at specular (off)
//! ```
//!
//! with θa = |θi − θr| / 2 and ψ = (θi + θr) / 2; F is the paper's Fresnel term exactly
//! as Akao et al. writes it, G Blinn's geometric attenuation, and D the facet distribution
//! normalised to 1 at its peak (θa = 0), so that ρs means the same for every [`Lobe`]:
//!
//! - [`Lobe::Gaussian`]: D = exp(−θa² / (2σ²)), θa and σ in degrees: the TSL lobe. With
//!   no forward lobe and no bump this is the TSL model.
//! - [`Lobe::Ggx`]: the Trowbridge–Reitz (GGX) distribution, D = α⁴ / (α² cos²θa + sin²θa)²,
//!   with α chosen so that D falls to ½ at the same θa as the Gaussian of the spot's σ
//!   (θa½ = σ·√(2 ln 2)): sin²θa½ = α²(√2 − 1)/(1 − α²). Tails fall as θa⁻⁴.
//! - [`Lobe::Cauchy`]: D = 1 / (1 + (θa/γ)²), γ = θa½: tails fall as θa⁻².
//!
//! So all three lobes have the same full width at half maximum in θr, 4·θa½ = 4.71σ
//! (the paper's FWHM of the TS lobe), and ggx and cauchy have heavier tails. F and
//! G/(cos θi cos θr) widen the whole specular term of every lobe a little, a heavy tail a
//! little more: for σ ≤ 1.9° at θi 20–60° the whole term's FWHM is within 2.3 % (ggx) and
//! 5.8 % (cauchy) of the Gaussian's (tests/it/sheet.rs).
//!
//! The two terms the TSL model lacks (the paper's last paragraph), each with a strength
//! that is a radiance factor:
//!
//! - **forward lobe** (fibrous papers scatter forward, a lobe at θr well beyond specular):
//!   `forward = F · u²`, u = clamp((θr − θi) / (90° − θi), 0, 1): nothing on the source's
//!   side of specular, rising smoothly (zero slope at specular) to F at grazing θr. At the
//!   same offset past specular it is larger at larger θi (u grows as 90° − θi shrinks),
//!   as forward scattering is.
//! - **specular bump** (J1 and J2 rise slightly around specular, less at θi = 60°):
//!   `bump = B · cos²θi · exp(−(θr − θi)² / (2 · w²))`, w = [`BUMP_SD_DEG`] = 2.5° in θr
//!   (FWHM 5.9°, far narrower than a rough paper's TS lobe: 79° for J1).
//!
//! A sheet is made of spots ([`SheetSpec::spot`]): with a between-spot variation each spot
//! draws its σ, ρs and ρd around the stock's, log-normally (always positive), with mean the
//! stock's value and relative standard deviation the given fraction:
//! x = x₀ · exp(s·z − s²/2), s² = ln(1 + p²), z ~ N(0, 1). η is a property of the material
//! and does not vary. Spot k's draws come from its own random stream of the seed, so spot
//! k is the same whatever else the run does.

use crate::scene::{Scene, Spots};
use rand_distr::{Distribution, StandardNormal};
use std::sync::Arc;

/// Standard deviation in θr of the specular bump, degrees.
pub const BUMP_SD_DEG: f64 = 2.5;

/// Largest σ for which a ggx or cauchy lobe can have the Gaussian's half-width inside
/// the hemisphere (θa½ = σ·√(2 ln 2) below 85°).
pub const MAX_HEAVY_TAILED_SIGMA_DEG: f64 = 72.0;

/// Random stream of spot k's draws: `SPOT_STREAM_BASE + k` (streams 0.. below are the
/// detector noise and the instrument's errors, see [`crate::streams`]).
const SPOT_STREAM_BASE: u64 = 1 << 32;

/// √(2 ln 2): the Gaussian exp(−x²/(2σ²)) is ½ at x = σ·√(2 ln 2).
const SQRT_2_LN_2: f64 = 1.177_410_022_515_474_6;

/// The microfacet-plus-Lambert parameters of a paper (or of one spot of it).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Stock {
    /// Spread of facet angles, degrees.
    pub sigma_deg: f64,
    /// Weight of the microfacet (specular) part.
    pub rho_s: f64,
    /// Weight of the Lambert (diffuse) part.
    pub rho_d: f64,
    /// Refractive index, in the Fresnel term only.
    pub eta: f64,
}

/// The facet distribution of the specular lobe.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Lobe {
    /// exp(−θa²/(2σ²)): the TSL lobe.
    #[default]
    Gaussian,
    /// Trowbridge–Reitz (GGX) with the Gaussian's FWHM.
    Ggx,
    /// Cauchy (Lorentzian) in θa with the Gaussian's FWHM.
    Cauchy,
}

/// Everything that makes a simulated sheet: the stock and what it does beyond TSL.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SheetSpec {
    /// The paper's parameters (the mean over spots).
    pub stock: Stock,
    /// The facet distribution.
    pub lobe: Lobe,
    /// Strength of the forward lobe: the radiance factor it adds at grazing θr.
    pub forward_lobe: f64,
    /// Strength of the specular bump: the radiance factor it adds at specular, θi = 0.
    pub specular_bump: f64,
    /// Relative standard deviation of σ, ρs and ρd between spots (0: every spot the stock).
    pub spot_variation: f64,
}

/// What is wrong with a sheet's description.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum SheetError {
    /// A parameter out of its range.
    #[error("{name} must be {range}, got {value}")]
    OutOfRange {
        /// Which parameter.
        name: &'static str,
        /// Its range, in words.
        range: &'static str,
        /// What was given.
        value: f64,
    },
}

impl SheetSpec {
    /// The plain TSL sheet of `stock`: Gaussian lobe, nothing else, every spot the same.
    pub fn tsl(stock: Stock) -> SheetSpec {
        SheetSpec {
            stock,
            lobe: Lobe::Gaussian,
            forward_lobe: 0.0,
            specular_bump: 0.0,
            spot_variation: 0.0,
        }
    }

    /// Check every parameter; the simulator's options are checked here.
    pub fn validate(&self) -> Result<(), SheetError> {
        let s = &self.stock;
        let check = |name, range, value: f64, ok: bool| {
            if ok && value.is_finite() {
                Ok(())
            } else {
                Err(SheetError::OutOfRange { name, range, value })
            }
        };
        check(
            "sigma",
            "in (0, 90] degrees",
            s.sigma_deg,
            s.sigma_deg > 0.0 && s.sigma_deg <= 90.0,
        )?;
        check("rho_s", "≥ 0", s.rho_s, s.rho_s >= 0.0)?;
        check("rho_d", "≥ 0", s.rho_d, s.rho_d >= 0.0)?;
        check("eta", "in [1, 3]", s.eta, (1.0..=3.0).contains(&s.eta))?;
        if self.lobe != Lobe::Gaussian {
            check(
                "sigma of a ggx or cauchy lobe",
                "at most 72 degrees (its half-width must lie inside the hemisphere)",
                s.sigma_deg,
                s.sigma_deg <= MAX_HEAVY_TAILED_SIGMA_DEG,
            )?;
        }
        check(
            "forward lobe",
            "a radiance factor in [0, 100]",
            self.forward_lobe,
            (0.0..=100.0).contains(&self.forward_lobe),
        )?;
        check(
            "specular bump",
            "a radiance factor in [0, 100]",
            self.specular_bump,
            (0.0..=100.0).contains(&self.specular_bump),
        )?;
        check(
            "sheet variation",
            "a fraction in [0, 0.5]",
            self.spot_variation,
            (0.0..=0.5).contains(&self.spot_variation),
        )?;
        Ok(())
    }

    /// Spot `index` of the sheet in the run of `seed`.
    pub fn spot(&self, seed: u64, index: u32) -> Sheet {
        let mut stock = self.stock;
        if self.spot_variation > 0.0 {
            let mut rng = crate::stream(seed, SPOT_STREAM_BASE + u64::from(index));
            let s2 = self.spot_variation.powi(2).ln_1p();
            let s = s2.sqrt();
            let mut draw = |x: f64| {
                let z: f64 = StandardNormal.sample(&mut rng);
                x * (s * z - 0.5 * s2).exp()
            };
            stock.sigma_deg = draw(stock.sigma_deg);
            stock.rho_s = draw(stock.rho_s);
            stock.rho_d = draw(stock.rho_d);
            // A spot is still a surface the lobe can describe.
            let max_sigma = if self.lobe == Lobe::Gaussian {
                90.0
            } else {
                MAX_HEAVY_TAILED_SIGMA_DEG
            };
            stock.sigma_deg = stock.sigma_deg.min(max_sigma);
        }
        Sheet::new(stock, self.lobe, self.forward_lobe, self.specular_bump)
    }
}

impl Spots for SheetSpec {
    fn spot(&self, seed: u64, index: u32) -> Arc<dyn Scene> {
        Arc::new(SheetSpec::spot(self, seed, index))
    }
}

/// One spot of a sheet: a [`Scene`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sheet {
    params: Stock,
    lobe: Lobe,
    /// α² of the GGX lobe, or γ (degrees) of the Cauchy lobe; unused for the Gaussian.
    shape: f64,
    forward_lobe: f64,
    specular_bump: f64,
}

impl Sheet {
    /// A spot with these parameters.
    pub fn new(params: Stock, lobe: Lobe, forward_lobe: f64, specular_bump: f64) -> Sheet {
        let half_width_deg = params.sigma_deg * SQRT_2_LN_2;
        let shape = match lobe {
            Lobe::Gaussian => 0.0,
            Lobe::Ggx => {
                let s = half_width_deg.to_radians().sin().powi(2);
                s / (s + std::f64::consts::SQRT_2 - 1.0)
            }
            Lobe::Cauchy => half_width_deg,
        };
        Sheet {
            params,
            lobe,
            shape,
            forward_lobe,
            specular_bump,
        }
    }

    /// The spot's parameters.
    pub fn params(&self) -> Stock {
        self.params
    }

    /// The facet distribution at half-angle `theta_a_deg`, 1 at its peak.
    pub fn distribution(&self, theta_a_deg: f64) -> f64 {
        match self.lobe {
            Lobe::Gaussian => {
                let t = theta_a_deg / self.params.sigma_deg;
                (-0.5 * t * t).exp()
            }
            Lobe::Ggx => {
                let alpha2 = self.shape;
                let (sin, cos) = theta_a_deg.to_radians().sin_cos();
                let den = alpha2 * cos * cos + sin * sin;
                alpha2 * alpha2 / (den * den)
            }
            Lobe::Cauchy => {
                let t = theta_a_deg / self.shape;
                1.0 / (1.0 + t * t)
            }
        }
    }

    /// The microfacet part alone (the term ρs scales).
    pub fn specular(&self, theta_i_deg: f64, theta_r_deg: f64) -> f64 {
        let psi = 0.5 * (theta_i_deg + theta_r_deg);
        let theta_a = 0.5 * (theta_i_deg - theta_r_deg).abs();
        let attenuation_over_cosines = blinn_attenuation_over_cosines(theta_i_deg, theta_r_deg);
        self.params.rho_s
            * fresnel(psi, self.params.eta)
            * attenuation_over_cosines
            * self.distribution(theta_a)
    }

    /// The forward lobe's term.
    pub fn forward(&self, theta_i_deg: f64, theta_r_deg: f64) -> f64 {
        if self.forward_lobe == 0.0 {
            return 0.0;
        }
        let u = ((theta_r_deg - theta_i_deg) / (90.0 - theta_i_deg)).clamp(0.0, 1.0);
        self.forward_lobe * u * u
    }

    /// The specular bump's term.
    pub fn bump(&self, theta_i_deg: f64, theta_r_deg: f64) -> f64 {
        if self.specular_bump == 0.0 {
            return 0.0;
        }
        let z = (theta_r_deg - theta_i_deg) / BUMP_SD_DEG;
        self.specular_bump * theta_i_deg.to_radians().cos().powi(2) * (-0.5 * z * z).exp()
    }
}

impl Scene for Sheet {
    fn radiance_factor(&self, theta_i_deg: f64, theta_r_deg: f64) -> f64 {
        self.specular(theta_i_deg, theta_r_deg)
            + self.params.rho_d
            + self.forward(theta_i_deg, theta_r_deg)
            + self.bump(theta_i_deg, theta_r_deg)
    }
}

/// The paper's Fresnel term as Akao et al. writes it: the root of the sum of the squared
/// amplitude ratios, F(ψ) = √((tan(ψ−δ)/tan(ψ+δ))² + (sin(ψ−δ)/sin(ψ+δ))²),
/// δ = asin(sin ψ / η), ψ in degrees.
///
/// The limits the text gives: F(0) = √2 (η−1)/(η+1) (both ratios are 0/0 at ψ = 0);
/// F ≡ 0 at η = 1; the first ratio is 0 where ψ + δ = 90°.
pub fn fresnel(psi_deg: f64, eta: f64) -> f64 {
    if eta <= 1.0 {
        return 0.0;
    }
    let psi = psi_deg.to_radians();
    if psi == 0.0 {
        return std::f64::consts::SQRT_2 * (eta - 1.0) / (eta + 1.0);
    }
    let delta = (psi.sin() / eta).asin();
    let sum = psi + delta;
    let difference = psi - delta;
    let tan_ratio = if sum.cos().abs() < 1e-15 {
        0.0
    } else {
        difference.tan() / sum.tan()
    };
    let sin_ratio = difference.sin() / sum.sin();
    tan_ratio.hypot(sin_ratio)
}

/// Blinn's geometric attenuation G = min(1, 2(n·a)(n·r)/(r·a), 2(n·a)(n·i)/(r·a)) with
/// n·i = cos θi, n·r = cos θr, n·a = cos θa, r·a = cos ψ.
pub fn blinn_attenuation(theta_i_deg: f64, theta_r_deg: f64) -> f64 {
    let (n_i, n_r, n_a, r_a) = cosines(theta_i_deg, theta_r_deg);
    1f64.min(2.0 * n_a * n_r / r_a).min(2.0 * n_a * n_i / r_a)
}

/// G / (cos θi · cos θr), the factor of the microfacet term. Divided term by term
/// (min(1/(n·i n·r), 2 n·a/(r·a n·i), 2 n·a/(r·a n·r))) so that it stays finite where
/// one cosine vanishes.
fn blinn_attenuation_over_cosines(theta_i_deg: f64, theta_r_deg: f64) -> f64 {
    let (n_i, n_r, n_a, r_a) = cosines(theta_i_deg, theta_r_deg);
    let floor = 1e-300;
    let (n_i, n_r) = (n_i.max(floor), n_r.max(floor));
    (1.0 / (n_i * n_r))
        .min(2.0 * n_a / (r_a * n_i))
        .min(2.0 * n_a / (r_a * n_r))
}

/// (n·i, n·r, n·a, r·a) in the specular plane.
fn cosines(theta_i_deg: f64, theta_r_deg: f64) -> (f64, f64, f64, f64) {
    let n_i = theta_i_deg.to_radians().cos();
    let n_r = theta_r_deg.to_radians().cos();
    let n_a = (0.5 * (theta_i_deg - theta_r_deg)).to_radians().cos();
    let r_a = (0.5 * (theta_i_deg + theta_r_deg))
        .to_radians()
        .cos()
        .max(1e-300);
    (n_i, n_r, n_a, r_a)
}

#[cfg(test)]
mod tests {
    use super::*;

    const G: Stock = Stock {
        sigma_deg: 0.8,
        rho_s: 57.8,
        rho_d: 0.855,
        eta: 1.19,
    };

    #[test]
    fn fresnel_has_the_limits_the_method_states() {
        for eta in [1.02, 1.19, 1.5, 3.0] {
            let at_zero = std::f64::consts::SQRT_2 * (eta - 1.0) / (eta + 1.0);
            assert_eq!(fresnel(0.0, eta), at_zero);
            // Continuous into ψ = 0.
            assert!((fresnel(1e-6, eta) / at_zero - 1.0).abs() < 1e-9, "η {eta}");
            assert!(
                (fresnel(-1e-3, eta) / at_zero - 1.0).abs() < 1e-6,
                "η {eta}"
            );
        }
        assert_eq!(fresnel(30.0, 1.0), 0.0);
        // Brewster: ψ + δ = 90° at tan ψ = η; the tan ratio vanishes there, F = |sin ratio|.
        let eta: f64 = 1.5;
        let brewster = eta.atan().to_degrees();
        let psi = brewster.to_radians();
        let delta = (psi.sin() / eta).asin();
        assert!(
            (fresnel(brewster, eta) - ((psi - delta).sin() / (psi + delta).sin()).abs()).abs()
                < 1e-12
        );
    }

    #[test]
    fn blinn_is_one_near_normal_and_falls_at_grazing() {
        assert_eq!(blinn_attenuation(20.0, 20.0), 1.0);
        assert!(blinn_attenuation(80.0, 10.0) < 1.0);
        assert!(blinn_attenuation_over_cosines(0.0, 90.0).is_finite());
    }

    #[test]
    fn every_lobe_is_one_at_its_peak_and_half_at_the_gaussian_half_width() {
        for sigma in [0.3, 0.8, 1.9, 16.7, 43.5, 72.0] {
            let half = sigma * SQRT_2_LN_2;
            for lobe in [Lobe::Gaussian, Lobe::Ggx, Lobe::Cauchy] {
                let sheet = Sheet::new(
                    Stock {
                        sigma_deg: sigma,
                        ..G
                    },
                    lobe,
                    0.0,
                    0.0,
                );
                assert_eq!(sheet.distribution(0.0), 1.0, "{lobe:?} σ {sigma}");
                assert!(
                    (sheet.distribution(half) - 0.5).abs() < 1e-12,
                    "{lobe:?} σ {sigma}: {}",
                    sheet.distribution(half)
                );
            }
        }
    }

    #[test]
    fn spots_are_the_stock_without_variation_and_repeat_by_seed_and_index() {
        let spec = SheetSpec::tsl(G);
        assert_eq!(spec.spot(1, 0).params(), G);
        assert_eq!(spec.spot(9, 5).params(), G);
        let varied = SheetSpec {
            spot_variation: 0.1,
            ..spec
        };
        assert_eq!(varied.spot(3, 2), varied.spot(3, 2));
        assert_ne!(varied.spot(3, 2), varied.spot(3, 1));
        assert_ne!(varied.spot(3, 2), varied.spot(4, 2));
        assert_eq!(varied.spot(3, 2).params().eta, G.eta);
    }

    #[test]
    fn bad_sheets_are_refused_by_name() {
        let bad = [
            SheetSpec::tsl(Stock {
                sigma_deg: 0.0,
                ..G
            }),
            SheetSpec::tsl(Stock {
                rho_s: f64::NAN,
                ..G
            }),
            SheetSpec::tsl(Stock { eta: 0.9, ..G }),
            SheetSpec {
                lobe: Lobe::Ggx,
                ..SheetSpec::tsl(Stock {
                    sigma_deg: 80.0,
                    ..G
                })
            },
            SheetSpec {
                forward_lobe: -1.0,
                ..SheetSpec::tsl(G)
            },
            SheetSpec {
                specular_bump: f64::INFINITY,
                ..SheetSpec::tsl(G)
            },
            SheetSpec {
                spot_variation: 0.9,
                ..SheetSpec::tsl(G)
            },
        ];
        for spec in bad {
            assert!(spec.validate().is_err(), "{spec:?}");
        }
        assert_eq!(SheetSpec::tsl(G).validate(), Ok(()));
    }
}
