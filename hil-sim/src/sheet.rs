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
//! **Departures from TSL** ([`Departures`], issue 28): the shapes real paper takes that
//! the model lacks, each with a strength whose default leaves the sheet exactly TSL, so
//! that an analysis can be tried on sheets that are not its model. Each is parametrised
//! so that the stock's σ, ρs and ρd keep the meaning the analysis is scored against
//! ([`SheetSpec::equivalent_truth`]):
//!
//! - **lobe weight** w: the facet distribution is w·D_lobe + (1 − w)·D_gaussian, both of
//!   the same half-maximum width (a surface with two facet populations; 1: the lobe alone).
//!   Two more lobes: [`Lobe::Beckmann`] and [`Lobe::BlinnPhong`].
//! - **haze** (h, σh): a second, broad Gaussian TS lobe, h·ρs·F·G/(cos θi cos θr)·
//!   exp(−θa²/(2σh²)), σh > σ: the fine roughness on top of a coating's gloss that makes
//!   a glossy print look hazy (ASTM E430's haze). Its peak is h times the main lobe's.
//! - **peak shift** δ: the main lobe centred at θr = θi + δ (θa measured from there): a
//!   sheet whose mean facet normal is tilted by δ/2 in the plane (cockle, a curl on the
//!   port) or an off-specular peak beyond what F and G give.
//! - **asymmetry** r: the main lobe's σ is 2σ·r/(1 + r) past its peak (toward grazing)
//!   and 2σ/(1 + r) before it: wider on the far side for r > 1, as forward-scattering
//!   fibres make it; the half-maximum width is the symmetric lobe's.
//! - **Fresnel-flat** t: F replaced by (1 − t)·F(ψ) + t·F(45°): a lobe whose strength does
//!   not follow the Fresnel factor (facets of another index, a pigment's own reflection,
//!   multiple scattering). Equal to the paper's F at ψ = 45°.
//! - **σ varying with θi** k: σ(θi) = σ·(1 + k·(θi − 45°)/45°): a lobe that narrows (k < 0)
//!   toward grazing incidence, as shadowing hides the steepest facets.
//! - **Oren–Nayar body** s: the Lambert term replaced by Oren and Nayar's rough diffuse
//!   surface (1994, their full model: the direct term and the interreflection term) of
//!   facet slope deviation s, in the specular plane on both sides of the normal (θr ≥ 0
//!   across the normal from the source: darker toward grazing; θr < 0 on the source's
//!   side: brighter toward retro-reflection).
//! - **grazing body** g: the body (1 − g) + g·(1 + cos 45°)/(cos θi + cos θr) times
//!   Lambert's: a blend with the Lommel–Seeliger law of single scattering in a turbid layer,
//!   which rises toward grazing incidence and viewing.
//! - **retro-reflection** (B, w): the body times 1 + B·exp(−g²/(2w²)), g = θi + θr the
//!   phase angle (0 at retro-reflection, θr = −θi): the opposition surge of a porous
//!   surface, whose shadows hide behind its own facets seen from the source's direction.
//!
//! Every body term is normalised to its value at θi = 45°, θr = 0° (the 45°/0° geometry
//! of diffuse reflectance): the body there is ρd whatever its shape.
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

/// Largest σ of a Beckmann lobe: beyond it (α² > ½) the Beckmann distribution with its
/// 1/cos⁴θa rises away from θa = 0, a lobe with no peak at specular and no half-maximum
/// width to match.
pub const MAX_BECKMANN_SIGMA_DEG: f64 = 39.0;

/// Incidence at which σ(θi) = σ when σ varies with θi, and the 45°/0° geometry at which
/// every body shape is normalised to ρd, degrees.
pub const REFERENCE_THETA_I_DEG: f64 = 45.0;

/// The angle ψ at which a Fresnel-flat lobe's factor equals the paper's F, degrees.
pub const FRESNEL_FLAT_PSI_DEG: f64 = 45.0;

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
    /// Beckmann, D = exp(−tan²θa/α²)/cos⁴θa, with the Gaussian's FWHM (σ ≤
    /// [`MAX_BECKMANN_SIGMA_DEG`]): the Cook–Torrance lobe; lighter far tails, a broader
    /// shoulder on rough sheets.
    Beckmann,
    /// Blinn–Phong, D = cosⁿθa, with the Gaussian's FWHM: near the Gaussian for narrow
    /// lobes, flatter-topped and cut off at θa = 90° for broad ones.
    BlinnPhong,
}

impl Lobe {
    /// The largest σ the lobe takes, degrees (its half-width must lie inside the
    /// hemisphere, and a Beckmann lobe must peak at specular).
    pub fn max_sigma_deg(self) -> f64 {
        match self {
            Lobe::Gaussian => 90.0,
            Lobe::Ggx | Lobe::Cauchy | Lobe::BlinnPhong => MAX_HEAVY_TAILED_SIGMA_DEG,
            Lobe::Beckmann => MAX_BECKMANN_SIGMA_DEG,
        }
    }

    /// The shape parameter matching the Gaussian of `sigma_deg`'s half-maximum point
    /// θa½ = σ·√(2 ln 2): α² (GGX, Beckmann), γ in degrees (Cauchy), n (Blinn–Phong), none
    /// for the Gaussian.
    fn shape(self, sigma_deg: f64) -> f64 {
        let half_width_deg = sigma_deg * SQRT_2_LN_2;
        match self {
            Lobe::Gaussian => 0.0,
            Lobe::Ggx => {
                let s = half_width_deg.to_radians().sin().powi(2);
                s / (s + std::f64::consts::SQRT_2 - 1.0)
            }
            Lobe::Cauchy => half_width_deg,
            // exp(−tan²h/α²)/cos⁴h = ½.
            Lobe::Beckmann => {
                let h = half_width_deg.to_radians();
                h.tan().powi(2) / (std::f64::consts::LN_2 - 4.0 * h.cos().ln())
            }
            // cosⁿh = ½.
            Lobe::BlinnPhong => -std::f64::consts::LN_2 / half_width_deg.to_radians().cos().ln(),
        }
    }

    /// The distribution at half-angle `theta_a_deg` for σ `sigma_deg` and its
    /// [`Lobe::shape`], 1 at its peak.
    fn value(self, shape: f64, sigma_deg: f64, theta_a_deg: f64) -> f64 {
        match self {
            Lobe::Gaussian => gaussian(sigma_deg, theta_a_deg),
            Lobe::Ggx => {
                let alpha2 = shape;
                let (sin, cos) = theta_a_deg.to_radians().sin_cos();
                let den = alpha2 * cos * cos + sin * sin;
                alpha2 * alpha2 / (den * den)
            }
            Lobe::Cauchy => {
                let t = theta_a_deg / shape;
                1.0 / (1.0 + t * t)
            }
            Lobe::Beckmann => {
                let (sin, cos) = theta_a_deg.to_radians().sin_cos();
                if cos <= 1e-12 {
                    return 0.0;
                }
                let tan2 = (sin / cos).powi(2);
                (-tan2 / shape).exp() / cos.powi(4)
            }
            Lobe::BlinnPhong => theta_a_deg.to_radians().cos().max(0.0).powf(shape),
        }
    }
}

/// exp(−x²/(2σ²)), x and σ in degrees.
fn gaussian(sigma_deg: f64, x_deg: f64) -> f64 {
    let t = x_deg / sigma_deg;
    (-0.5 * t * t).exp()
}

/// What a sheet does beyond its lobe's shape, each departure from TSL with its strength
/// (the module's text says what each models). [`Departures::NONE`] is the TSL sheet.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Departures {
    /// Weight of the [`Lobe`] in a blend with the Gaussian of the same half-maximum width,
    /// in [0, 1] (1: the lobe alone).
    pub lobe_weight: f64,
    /// Haze lobe's peak as a fraction of the main lobe's, in [0, 1] (0: none).
    pub haze: f64,
    /// Haze lobe's σ, degrees: wider than the main lobe's, at most 90.
    pub haze_sigma_deg: f64,
    /// The main lobe's peak at θr = θi + this, degrees.
    pub peak_shift_deg: f64,
    /// The main lobe's σ past its peak over σ before it (1: symmetric).
    pub asymmetry: f64,
    /// How far the Fresnel factor is flattened to its value at ψ = 45°, in [0, 1].
    pub fresnel_flat: f64,
    /// k of σ(θi) = σ·(1 + k·(θi − 45°)/45°), in [−0.9, 0.9].
    pub sigma_slope: f64,
    /// Oren–Nayar roughness of the body (its facets' slope deviation), degrees (0: Lambert).
    pub oren_nayar_deg: f64,
    /// Weight of the Lommel–Seeliger law in the body, in [0, 1] (0: Lambert).
    pub grazing: f64,
    /// Retro-reflection surge of the body at retro-reflection, a fraction of it (0: none).
    pub retro: f64,
    /// The surge's standard deviation in phase angle, degrees.
    pub retro_width_deg: f64,
}

impl Departures {
    /// No departure: the TSL sheet.
    pub const NONE: Departures = Departures {
        lobe_weight: 1.0,
        haze: 0.0,
        haze_sigma_deg: 0.0,
        peak_shift_deg: 0.0,
        asymmetry: 1.0,
        fresnel_flat: 0.0,
        sigma_slope: 0.0,
        oren_nayar_deg: 0.0,
        grazing: 0.0,
        retro: 0.0,
        retro_width_deg: 0.0,
    };

    /// The largest σ the main lobe takes over θi in [0°, 90°] and both sides of its peak,
    /// per unit of the stock's σ.
    pub fn widest_sigma_factor(&self) -> f64 {
        let r = self.asymmetry;
        (1.0 + self.sigma_slope.abs()) * 2.0 * r.max(1.0) / (1.0 + r)
    }

    /// Whether the main lobe is the stock's at every geometry (no shift, no asymmetry, no
    /// σ varying with θi, no blend).
    fn plain_main_lobe(&self) -> bool {
        self.peak_shift_deg == 0.0
            && self.asymmetry == 1.0
            && self.sigma_slope == 0.0
            && self.lobe_weight == 1.0
    }
}

impl Default for Departures {
    fn default() -> Self {
        Departures::NONE
    }
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
    /// Departures from TSL ([`Departures::NONE`]: none).
    pub departures: Departures,
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
            departures: Departures::NONE,
        }
    }

    /// The TSL parameters an analysis of this sheet is scored against, the project's
    /// convention: σ of the Gaussian with the main lobe's half-maximum width (at θi = 45°
    /// where σ varies with θi), ρs of the main lobe (its peak is ρs·F·G/(cos θi cos θr)
    /// with the paper's F at ψ = 45°), ρd the body's radiance factor at θi = 45°, θr = 0°,
    /// and the stock's η (nominal: a Fresnel-flat lobe has none). Each departure is
    /// parametrised so that these are the stock's numbers:
    ///
    /// - lobe and lobe weight: every lobe is matched to the Gaussian's half-maximum point,
    ///   and so is a blend of two; peak 1, so ρs keeps its meaning;
    /// - haze: the main lobe's, not the sum's (the haze lobe widens the sum a little);
    /// - peak shift: the lobe is moved, not widened;
    /// - asymmetry: the two sides' σ average σ, so the half-maximum width is the
    ///   symmetric lobe's;
    /// - Fresnel-flat: the factor equals the paper's F at ψ = 45°;
    /// - σ varying with θi: σ(45°) = σ;
    /// - Oren–Nayar, grazing and retro-reflection bodies: normalised to ρd at 45°/0°.
    ///
    /// The unit tests measure each of these on the sheet's own functions. The class to
    /// expect is the underlying paper's (the analysis's business, not the simulator's).
    pub fn equivalent_truth(&self) -> Stock {
        self.stock
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
        match self.lobe {
            Lobe::Gaussian => {}
            Lobe::Beckmann => check(
                "sigma of a beckmann lobe",
                "at most 39 degrees (beyond, the Beckmann distribution does not peak at specular)",
                s.sigma_deg,
                s.sigma_deg <= MAX_BECKMANN_SIGMA_DEG,
            )?,
            Lobe::Ggx | Lobe::Cauchy | Lobe::BlinnPhong => check(
                "sigma of a ggx, cauchy or blinn-phong lobe",
                "at most 72 degrees (its half-width must lie inside the hemisphere)",
                s.sigma_deg,
                s.sigma_deg <= MAX_HEAVY_TAILED_SIGMA_DEG,
            )?,
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
        self.validate_departures()
    }

    /// Check the departures from TSL (part of [`SheetSpec::validate`]).
    fn validate_departures(&self) -> Result<(), SheetError> {
        let d = &self.departures;
        let check = |name, range, value: f64, ok: bool| {
            if ok && value.is_finite() {
                Ok(())
            } else {
                Err(SheetError::OutOfRange { name, range, value })
            }
        };
        let fraction =
            |name, value: f64| check(name, "in [0, 1]", value, (0.0..=1.0).contains(&value));
        fraction("lobe weight", d.lobe_weight)?;
        fraction("haze", d.haze)?;
        if d.haze > 0.0 {
            check(
                "haze sigma",
                "wider than the main lobe's sigma and at most 90 degrees",
                d.haze_sigma_deg,
                d.haze_sigma_deg > self.stock.sigma_deg && d.haze_sigma_deg <= 90.0,
            )?;
        }
        check(
            "peak shift",
            "in [-45, 45] degrees",
            d.peak_shift_deg,
            (-45.0..=45.0).contains(&d.peak_shift_deg),
        )?;
        check(
            "asymmetry",
            "a ratio of the two sides' sigma in [0.2, 5]",
            d.asymmetry,
            (0.2..=5.0).contains(&d.asymmetry),
        )?;
        fraction("fresnel flat", d.fresnel_flat)?;
        check(
            "sigma slope",
            "in [-0.9, 0.9] (sigma must stay positive from normal to grazing incidence)",
            d.sigma_slope,
            (-0.9..=0.9).contains(&d.sigma_slope),
        )?;
        check(
            "oren-nayar roughness",
            "in [0, 60] degrees",
            d.oren_nayar_deg,
            (0.0..=60.0).contains(&d.oren_nayar_deg),
        )?;
        fraction("grazing", d.grazing)?;
        check(
            "retro",
            "a fraction of the body in [0, 10]",
            d.retro,
            (0.0..=10.0).contains(&d.retro),
        )?;
        if d.retro > 0.0 {
            check(
                "retro width",
                "in (0, 90] degrees",
                d.retro_width_deg,
                d.retro_width_deg > 0.0 && d.retro_width_deg <= 90.0,
            )?;
        }
        let widest = self.stock.sigma_deg * d.widest_sigma_factor();
        check(
            "largest sigma of the lobe over incidence and its two sides (sigma × (1 + |sigma slope|) × 2·max(asymmetry, 1)/(1 + asymmetry))",
            "at most the lobe's largest sigma (gaussian 90 degrees; ggx, cauchy, blinn-phong 72; beckmann 39)",
            widest,
            widest <= self.lobe.max_sigma_deg(),
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
            // A spot is still a surface the lobe can describe, at every incidence.
            let max_sigma = self.lobe.max_sigma_deg() / self.departures.widest_sigma_factor();
            stock.sigma_deg = stock.sigma_deg.min(max_sigma);
        }
        Sheet::new(stock, self.lobe, self.forward_lobe, self.specular_bump)
            .with_departures(self.departures)
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
    /// The lobe's shape parameter for the spot's σ ([`Lobe::shape`]).
    shape: f64,
    forward_lobe: f64,
    specular_bump: f64,
    departures: Departures,
    /// Albedo of the Oren–Nayar body whose radiance factor at 45°/0° is ρd (0 without one).
    oren_nayar_albedo: f64,
}

impl Sheet {
    /// A spot with these parameters (no departure from TSL but the lobe's shape and the two
    /// terms given: [`Sheet::with_departures`] adds them).
    pub fn new(params: Stock, lobe: Lobe, forward_lobe: f64, specular_bump: f64) -> Sheet {
        Sheet {
            params,
            lobe,
            shape: lobe.shape(params.sigma_deg),
            forward_lobe,
            specular_bump,
            departures: Departures::NONE,
            oren_nayar_albedo: 0.0,
        }
    }

    /// The spot with these departures from TSL.
    pub fn with_departures(mut self, departures: Departures) -> Sheet {
        self.departures = departures;
        self.oren_nayar_albedo = if departures.oren_nayar_deg > 0.0 {
            // ρ·C1 + ρ²·a = ρd: the body at 45°/0° (β = 0) is ρd.
            let (c1, _, a) = oren_nayar_coefficients(departures.oren_nayar_deg);
            let rho_d = self.params.rho_d;
            2.0 * rho_d / (c1 + (c1 * c1 + 4.0 * a * rho_d).sqrt())
        } else {
            0.0
        };
        self
    }

    /// The spot's parameters.
    pub fn params(&self) -> Stock {
        self.params
    }

    /// The facet distribution of the spot's σ at half-angle `theta_a_deg`, 1 at its peak
    /// (the lobe weight's blend included).
    pub fn distribution(&self, theta_a_deg: f64) -> f64 {
        self.distribution_of(self.params.sigma_deg, theta_a_deg)
    }

    /// The facet distribution of σ `sigma_deg` at half-angle `theta_a_deg`, 1 at its peak.
    fn distribution_of(&self, sigma_deg: f64, theta_a_deg: f64) -> f64 {
        // The shape of the spot's own σ is computed once; a σ that varies, each time.
        let shape = if sigma_deg == self.params.sigma_deg {
            self.shape
        } else {
            self.lobe.shape(sigma_deg)
        };
        let lobe = self.lobe.value(shape, sigma_deg, theta_a_deg);
        let w = self.departures.lobe_weight;
        if w == 1.0 || self.lobe == Lobe::Gaussian {
            lobe
        } else {
            w * lobe + (1.0 - w) * gaussian(sigma_deg, theta_a_deg)
        }
    }

    /// σ of the main lobe at incidence `theta_i_deg` on one side of its peak (`past`: θr
    /// beyond it, toward grazing), degrees.
    pub fn sigma_at(&self, theta_i_deg: f64, past: bool) -> f64 {
        let d = &self.departures;
        let mut sigma = self.params.sigma_deg;
        if d.sigma_slope != 0.0 {
            sigma *=
                1.0 + d.sigma_slope * (theta_i_deg - REFERENCE_THETA_I_DEG) / REFERENCE_THETA_I_DEG;
        }
        if d.asymmetry != 1.0 {
            let r = d.asymmetry;
            sigma *= if past {
                2.0 * r / (1.0 + r)
            } else {
                2.0 / (1.0 + r)
            };
        }
        sigma
    }

    /// The main lobe's facet distribution at this geometry, 1 at its peak (θr = θi + the
    /// peak shift).
    pub fn main_lobe(&self, theta_i_deg: f64, theta_r_deg: f64) -> f64 {
        let d = &self.departures;
        if d.plain_main_lobe() {
            return self.distribution(0.5 * (theta_i_deg - theta_r_deg).abs());
        }
        let offset = theta_r_deg - d.peak_shift_deg - theta_i_deg;
        let sigma = self.sigma_at(theta_i_deg, offset > 0.0);
        self.distribution_of(sigma, 0.5 * offset.abs())
    }

    /// The Fresnel factor of the lobes at ψ: the paper's, or flattened toward F(45°).
    pub fn fresnel_factor(&self, psi_deg: f64) -> f64 {
        let f = fresnel(psi_deg, self.params.eta);
        let t = self.departures.fresnel_flat;
        if t == 0.0 {
            f
        } else {
            (1.0 - t) * f + t * fresnel(FRESNEL_FLAT_PSI_DEG, self.params.eta)
        }
    }

    /// The microfacet part alone (the terms ρs scales: the main lobe and the haze lobe).
    pub fn specular(&self, theta_i_deg: f64, theta_r_deg: f64) -> f64 {
        let psi = 0.5 * (theta_i_deg + theta_r_deg);
        let attenuation_over_cosines = blinn_attenuation_over_cosines(theta_i_deg, theta_r_deg);
        let fresnel = self.fresnel_factor(psi);
        let main = self.params.rho_s
            * fresnel
            * attenuation_over_cosines
            * self.main_lobe(theta_i_deg, theta_r_deg);
        let d = &self.departures;
        if d.haze == 0.0 {
            return main;
        }
        let theta_a = 0.5 * (theta_i_deg - theta_r_deg).abs();
        main + self.params.rho_s
            * d.haze
            * fresnel
            * attenuation_over_cosines
            * gaussian(d.haze_sigma_deg, theta_a)
    }

    /// The diffuse body: ρd (Lambert) times the shape of each body departure, each 1 at
    /// θi = 45°, θr = 0°.
    pub fn body(&self, theta_i_deg: f64, theta_r_deg: f64) -> f64 {
        let d = &self.departures;
        let mut body = self.params.rho_d;
        if d.oren_nayar_deg > 0.0 {
            body *= self.oren_nayar_shape(theta_i_deg, theta_r_deg);
        }
        if d.grazing > 0.0 {
            let cosines =
                (theta_i_deg.to_radians().cos() + theta_r_deg.to_radians().cos()).max(1e-9);
            body *= (1.0 - d.grazing)
                + d.grazing * (1.0 + REFERENCE_THETA_I_DEG.to_radians().cos()) / cosines;
        }
        if d.retro > 0.0 {
            let surge = |phase_deg: f64| 1.0 + d.retro * gaussian(d.retro_width_deg, phase_deg);
            body *= surge(theta_i_deg + theta_r_deg) / surge(REFERENCE_THETA_I_DEG);
        }
        body
    }

    /// Oren and Nayar's body (1994: the direct term with C1, C2, C3 and the interreflection
    /// term) in the specular plane over its value at 45°/0°, for the albedo whose body there is ρd.
    /// θr ≥ 0 is across the normal from the source (azimuth difference π: the cos φ terms
    /// −1; the C3 term vanishes in the plane), θr < 0 on the source's side (cos φ = 1).
    fn oren_nayar_shape(&self, theta_i_deg: f64, theta_r_deg: f64) -> f64 {
        let (c1, c2_scale, a) = oren_nayar_coefficients(self.departures.oren_nayar_deg);
        let (ti, tr) = (
            theta_i_deg.abs().to_radians(),
            theta_r_deg.abs().to_radians(),
        );
        let (alpha, beta) = (ti.max(tr), ti.min(tr));
        let across = theta_r_deg >= 0.0;
        let cos_phi = if across { -1.0 } else { 1.0 };
        let b = 2.0 * beta / std::f64::consts::PI;
        let c2 = if across {
            c2_scale * (alpha.sin() - b.powi(3))
        } else {
            c2_scale * alpha.sin()
        };
        let direct = c1 + cos_phi * c2 * beta.tan();
        let interreflected = a * (1.0 - cos_phi * b * b);
        let rho = self.oren_nayar_albedo;
        (direct + rho * interreflected) / (c1 + rho * a)
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
            + self.body(theta_i_deg, theta_r_deg)
            + self.forward(theta_i_deg, theta_r_deg)
            + self.bump(theta_i_deg, theta_r_deg)
    }
}

/// Oren–Nayar's (C1, the scale of C2, the interreflection's a) for facet slope deviation
/// `roughness_deg` (σ in radians in their formulas).
fn oren_nayar_coefficients(roughness_deg: f64) -> (f64, f64, f64) {
    let s2 = roughness_deg.to_radians().powi(2);
    (
        1.0 - 0.5 * s2 / (s2 + 0.33),
        0.45 * s2 / (s2 + 0.09),
        0.17 * s2 / (s2 + 0.13),
    )
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

    /// Every departure alone, at a strength a campaign would use.
    fn departures() -> Vec<(&'static str, Lobe, Departures)> {
        let d = Departures::NONE;
        vec![
            ("none", Lobe::Gaussian, d),
            (
                "ggx half",
                Lobe::Ggx,
                Departures {
                    lobe_weight: 0.5,
                    ..d
                },
            ),
            ("beckmann", Lobe::Beckmann, d),
            ("blinn-phong", Lobe::BlinnPhong, d),
            (
                "blinn-phong half",
                Lobe::BlinnPhong,
                Departures {
                    lobe_weight: 0.5,
                    ..d
                },
            ),
            ("cauchy", Lobe::Cauchy, d),
            (
                "haze",
                Lobe::Gaussian,
                Departures {
                    haze: 0.03,
                    haze_sigma_deg: 60.0,
                    ..d
                },
            ),
            (
                "shift",
                Lobe::Gaussian,
                Departures {
                    peak_shift_deg: 0.7,
                    ..d
                },
            ),
            (
                "asymmetry",
                Lobe::Gaussian,
                Departures {
                    asymmetry: 2.0,
                    ..d
                },
            ),
            (
                "asymmetric ggx",
                Lobe::Ggx,
                Departures {
                    asymmetry: 0.6,
                    ..d
                },
            ),
            (
                "fresnel-flat",
                Lobe::Gaussian,
                Departures {
                    fresnel_flat: 1.0,
                    ..d
                },
            ),
            (
                "sigma slope",
                Lobe::Gaussian,
                Departures {
                    sigma_slope: -0.4,
                    ..d
                },
            ),
            (
                "oren-nayar",
                Lobe::Gaussian,
                Departures {
                    oren_nayar_deg: 30.0,
                    ..d
                },
            ),
            ("grazing", Lobe::Gaussian, Departures { grazing: 1.0, ..d }),
            (
                "retro",
                Lobe::Gaussian,
                Departures {
                    retro: 1.0,
                    retro_width_deg: 15.0,
                    ..d
                },
            ),
            (
                "all bodies",
                Lobe::Gaussian,
                Departures {
                    oren_nayar_deg: 20.0,
                    grazing: 0.5,
                    retro: 0.5,
                    retro_width_deg: 10.0,
                    ..d
                },
            ),
        ]
    }

    /// Where a side of the main lobe at θi = 45° falls to ½: the offset from its peak in θr,
    /// degrees, by bisection (each side falls monotonically).
    fn half_maximum_offset(sheet: &Sheet, peak_deg: f64, sign: f64) -> f64 {
        let (mut lo, mut hi) = (0.0, 179.0);
        for _ in 0..200 {
            let mid = 0.5 * (lo + hi);
            if sheet.main_lobe(45.0, peak_deg + sign * mid) > 0.5 {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        0.5 * (lo + hi)
    }

    #[test]
    fn the_equivalent_truth_is_what_the_sheet_does_at_the_reference_geometries() {
        let stocks = [
            G,
            Stock {
                sigma_deg: 16.7,
                rho_s: 0.734,
                rho_d: 0.127,
                eta: 3.0,
            },
            Stock {
                sigma_deg: 30.0,
                rho_s: 0.123,
                rho_d: 0.642,
                eta: 3.0,
            },
        ];
        for stock in stocks {
            for (name, lobe, d) in departures() {
                let spec = SheetSpec {
                    lobe,
                    departures: d,
                    ..SheetSpec::tsl(stock)
                };
                assert_eq!(spec.validate(), Ok(()), "{name}");
                let truth = spec.equivalent_truth();
                let sheet = spec.spot(1, 0);
                let what = format!("{name} on σ {}", stock.sigma_deg);
                // σ: the Gaussian of the main lobe's half-maximum width (4·θa½ in θr).
                let peak = 45.0 + d.peak_shift_deg;
                assert_eq!(sheet.main_lobe(45.0, peak), 1.0, "{what}");
                let width = half_maximum_offset(&sheet, peak, 1.0)
                    + half_maximum_offset(&sheet, peak, -1.0);
                let sigma_eq = width / (4.0 * SQRT_2_LN_2);
                assert!(
                    (sigma_eq / truth.sigma_deg - 1.0).abs() < 1e-9,
                    "{what}: σ_eq {sigma_eq} against {}",
                    truth.sigma_deg
                );
                // ρs: the main lobe peaks at 1 with the paper's F at ψ = 45°.
                assert_eq!(truth.rho_s, stock.rho_s);
                assert!(
                    (sheet.fresnel_factor(FRESNEL_FLAT_PSI_DEG) / fresnel(45.0, stock.eta) - 1.0)
                        .abs()
                        < 1e-12,
                    "{what}"
                );
                // ρd: the body at 45°/0°.
                assert!(
                    (sheet.body(45.0, 0.0) / truth.rho_d - 1.0).abs() < 1e-12,
                    "{what}: body {}",
                    sheet.body(45.0, 0.0)
                );
                assert_eq!(truth.eta, stock.eta);
            }
        }
    }

    #[test]
    fn without_departures_the_sheet_is_the_tsl_formula_bit_for_bit() {
        for (lobe, stock) in [(Lobe::Gaussian, G), (Lobe::Ggx, G), (Lobe::Cauchy, G)] {
            let plain = Sheet::new(stock, lobe, 0.0, 0.0);
            assert_eq!(plain.with_departures(Departures::NONE), plain);
            assert_eq!(
                SheetSpec {
                    lobe,
                    ..SheetSpec::tsl(stock)
                }
                .spot(2, 0),
                plain
            );
            for (ti, tr) in [
                (20.0_f64, 0.0_f64),
                (20.0, 20.3),
                (60.0, 58.1),
                (60.0, -0.4),
                (45.0, 70.0),
            ] {
                let theta_a = 0.5 * (ti - tr).abs();
                let expected = stock.rho_s
                    * fresnel(0.5 * (ti + tr), stock.eta)
                    * blinn_attenuation_over_cosines(ti, tr)
                    * plain.distribution(theta_a)
                    + stock.rho_d;
                assert_eq!(
                    plain.radiance_factor(ti, tr),
                    expected,
                    "{lobe:?} {ti} {tr}"
                );
            }
        }
    }

    #[test]
    fn each_departure_bends_the_sheet_the_way_it_models() {
        let stock = Stock {
            sigma_deg: 10.0,
            rho_s: 1.0,
            rho_d: 0.5,
            eta: 1.5,
        };
        let with = |lobe, d| {
            SheetSpec {
                lobe,
                departures: d,
                ..SheetSpec::tsl(stock)
            }
            .spot(1, 0)
        };
        let plain = with(Lobe::Gaussian, Departures::NONE);
        let d = Departures::NONE;
        // Haze: more light far from specular, the same main lobe.
        let haze = with(
            Lobe::Gaussian,
            Departures {
                haze: 0.05,
                haze_sigma_deg: 40.0,
                ..d
            },
        );
        assert!(haze.specular(30.0, 89.0) > 2.0 * plain.specular(30.0, 89.0));
        assert_eq!(haze.main_lobe(30.0, 50.0), plain.main_lobe(30.0, 50.0));
        // Peak shift: the lobe's peak moves to θr = θi + δ.
        let shifted = with(
            Lobe::Gaussian,
            Departures {
                peak_shift_deg: 3.0,
                ..d
            },
        );
        assert_eq!(shifted.main_lobe(30.0, 33.0), 1.0);
        assert!(shifted.main_lobe(30.0, 35.0) > shifted.main_lobe(30.0, 30.0));
        // Asymmetry: wider past the peak for r > 1.
        let skewed = with(
            Lobe::Gaussian,
            Departures {
                asymmetry: 2.0,
                ..d
            },
        );
        assert!(skewed.main_lobe(30.0, 50.0) > skewed.main_lobe(30.0, 10.0));
        // Fresnel-flat: the same at ψ = 45°, not growing toward grazing as F does.
        let flat = with(
            Lobe::Gaussian,
            Departures {
                fresnel_flat: 1.0,
                ..d
            },
        );
        assert_eq!(flat.fresnel_factor(10.0), flat.fresnel_factor(80.0));
        assert!(plain.fresnel_factor(80.0) > plain.fresnel_factor(10.0));
        // σ varying with θi: narrower at 60° than at 20° for k < 0, σ at 45°.
        let varying = with(
            Lobe::Gaussian,
            Departures {
                sigma_slope: -0.4,
                ..d
            },
        );
        assert!(varying.sigma_at(60.0, true) < varying.sigma_at(20.0, true));
        assert!((varying.sigma_at(45.0, true) - 10.0).abs() < 1e-12);
        // Oren–Nayar: darker toward grazing across the normal, brighter toward retro.
        let rough = with(
            Lobe::Gaussian,
            Departures {
                oren_nayar_deg: 30.0,
                ..d
            },
        );
        assert!(rough.body(60.0, 70.0) < rough.body(60.0, 0.0));
        assert!(rough.body(60.0, -50.0) > rough.body(60.0, 0.0));
        // Continuous through the normal.
        assert!((rough.body(60.0, 1e-9) - rough.body(60.0, -1e-9)).abs() < 1e-9);
        // Grazing: the body rises toward grazing viewing and incidence.
        let grazing = with(Lobe::Gaussian, Departures { grazing: 1.0, ..d });
        assert!(grazing.body(60.0, 70.0) > grazing.body(60.0, 10.0));
        assert!(grazing.body(70.0, 10.0) > grazing.body(20.0, 10.0));
        // Retro-reflection: the body peaks at θr = −θi.
        let retro = with(
            Lobe::Gaussian,
            Departures {
                retro: 1.0,
                retro_width_deg: 10.0,
                ..d
            },
        );
        assert!(retro.body(20.0, -20.0) > 1.9 * retro.body(20.0, 20.0));
        assert!(retro.body(20.0, 0.0) > retro.body(20.0, 20.0));
        for sheet in [haze, shifted, skewed, flat, varying, rough, grazing, retro] {
            for ti in [0.0, 20.0, 60.0, 80.0] {
                for tr in [-10.0, 0.0, 20.0, 60.0, 89.0] {
                    let f = sheet.radiance_factor(ti, tr);
                    assert!(f.is_finite() && f >= 0.0, "{sheet:?} at {ti} {tr}: {f}");
                }
            }
        }
    }

    #[test]
    fn the_new_lobes_are_one_at_the_peak_and_half_at_the_gaussian_half_width() {
        for sigma in [0.3, 0.8, 1.9, 16.7, 39.0] {
            let half = sigma * SQRT_2_LN_2;
            for lobe in [Lobe::Beckmann, Lobe::BlinnPhong] {
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
                    "{lobe:?} σ {sigma}"
                );
                // A lobe: falling from its peak.
                let mut last = 1.0;
                for k in 1..=89 {
                    let value = sheet.distribution(f64::from(k));
                    assert!(value <= last, "{lobe:?} σ {sigma} at {k}°");
                    last = value;
                }
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
            SheetSpec {
                lobe: Lobe::Beckmann,
                ..SheetSpec::tsl(Stock {
                    sigma_deg: 43.5,
                    ..G
                })
            },
        ];
        for spec in bad {
            assert!(spec.validate().is_err(), "{spec:?}");
        }
        assert_eq!(SheetSpec::tsl(G).validate(), Ok(()));
        let d = Departures::NONE;
        for (departures, says) in [
            (
                Departures {
                    lobe_weight: 1.5,
                    ..d
                },
                "lobe weight must be in [0, 1], got 1.5",
            ),
            (
                Departures {
                    haze: 0.03,
                    haze_sigma_deg: 0.5,
                    ..d
                },
                "haze sigma must be wider",
            ),
            (Departures { haze: -0.1, ..d }, "haze must be in [0, 1]"),
            (
                Departures {
                    peak_shift_deg: f64::NAN,
                    ..d
                },
                "peak shift must be in [-45, 45] degrees, got NaN",
            ),
            (
                Departures {
                    asymmetry: 0.0,
                    ..d
                },
                "asymmetry must be a ratio",
            ),
            (
                Departures {
                    fresnel_flat: 2.0,
                    ..d
                },
                "fresnel flat must be in [0, 1]",
            ),
            (
                Departures {
                    sigma_slope: 1.0,
                    ..d
                },
                "sigma slope must be in [-0.9, 0.9]",
            ),
            (
                Departures {
                    oren_nayar_deg: -5.0,
                    ..d
                },
                "oren-nayar roughness must be in [0, 60]",
            ),
            (
                Departures { grazing: 1.1, ..d },
                "grazing must be in [0, 1]",
            ),
            (
                Departures { retro: 0.5, ..d },
                "retro width must be in (0, 90] degrees, got 0",
            ),
        ] {
            let error = SheetSpec {
                departures,
                ..SheetSpec::tsl(G)
            }
            .validate()
            .unwrap_err()
            .to_string();
            assert!(error.starts_with(says), "{error}");
        }
        // σ that varies must stay within the lobe's range at every incidence and side.
        let wide = SheetSpec {
            lobe: Lobe::Ggx,
            departures: Departures {
                sigma_slope: 0.5,
                ..d
            },
            ..SheetSpec::tsl(Stock {
                sigma_deg: 60.0,
                ..G
            })
        };
        let error = wide.validate().unwrap_err().to_string();
        assert!(
            error.starts_with("largest sigma of the lobe") && error.contains("90"),
            "{error}"
        );
        // A varied spot is clamped to what its lobe takes at every incidence.
        let varied = SheetSpec {
            spot_variation: 0.5,
            ..wide
        };
        for k in 0..50 {
            let sigma = varied.spot(7, k).params().sigma_deg;
            assert!(
                sigma * 1.5 <= MAX_HEAVY_TAILED_SIGMA_DEG + 1e-9,
                "spot {k}: {sigma}"
            );
        }
    }
}
