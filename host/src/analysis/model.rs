//! The Torrance–Sparrow + Lambert (TSL) reflectance model in the specular plane
//! (METHOD.md, Eq. 1–4), its analytic derivatives, and the detector's angular acceptance.
//!
//! Radiance factor (BRDF × π):
//!
//! ```text
//! f(θi, θr) = ρs · F(ψ) · G / (cos θi · cos θr) · exp(−θa² / (2σ²)) + ρd
//! ```
//!
//! with θa = |θi − θr| / 2 and ψ = (θi + θr) / 2, θa and σ in degrees. Angles are in
//! degrees throughout; θr may be negative (the detector past the normal, on the source's
//! side), which the acceptance window needs near θr = 0.

use serde::Serialize;

/// Full width of the detector's angular acceptance in θr, degrees (INSTRUMENT.md).
pub const DEFAULT_ACCEPTANCE_DEG: f64 = 1.0;

/// The acceptance is modelled when the lobe's FWHM in θr is below this many acceptance
/// widths. At the threshold the window changes the peak by about a² / (24 (2σ)²) ≈ 0.2 %,
/// below the instrument's noise; rough papers (σ ≫ 2°) never reach it.
pub const ACCEPTANCE_FWHM_RATIO: f64 = 10.0;

/// FWHM of the TS lobe in θr per degree of σ: the lobe has standard deviation 2σ in θr.
pub const FWHM_PER_SIGMA: f64 = 4.0 * 1.177_410_022_515_474_6; // 4·sqrt(2 ln 2)

/// Index of σ in gradient arrays.
pub const SIGMA: usize = 0;
/// Index of ρs in gradient arrays.
pub const RHO_S: usize = 1;
/// Index of ρd in gradient arrays.
pub const RHO_D: usize = 2;
/// Index of η in gradient arrays.
pub const ETA: usize = 3;
/// Parameter names in gradient order, as the JSON output spells them.
pub const PARAM_NAMES: [&str; 4] = ["sigma", "rho_s", "rho_d", "eta"];

/// The four TSL parameters.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Params {
    /// Spread of facet angles, degrees (> 0).
    pub sigma_deg: f64,
    /// Weight of the specular (Torrance–Sparrow) part.
    pub rho_s: f64,
    /// Weight of the diffuse (Lambert) part.
    pub rho_d: f64,
    /// Refractive index (≥ 1), used only in the Fresnel term.
    pub eta: f64,
}

impl Params {
    /// Parameters in gradient order.
    pub fn to_array(self) -> [f64; 4] {
        [self.sigma_deg, self.rho_s, self.rho_d, self.eta]
    }

    /// Parameters from an array in gradient order.
    pub fn from_array(a: [f64; 4]) -> Params {
        Params { sigma_deg: a[SIGMA], rho_s: a[RHO_S], rho_d: a[RHO_D], eta: a[ETA] }
    }
}

/// Smallest cosine used; keeps exactly-grazing geometries finite.
const COS_FLOOR: f64 = 1e-300;

/// The parts of the model that depend only on the geometry.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlaneGeometry {
    /// θr − θi, degrees (the lobe's coordinate; θa = |offset| / 2).
    pub offset_deg: f64,
    /// sin² ψ.
    pub sin2_psi: f64,
    /// cos ψ.
    pub cos_psi: f64,
    /// G / (cos θi · cos θr).
    pub attenuation_over_cosines: f64,
}

impl PlaneGeometry {
    /// Geometry terms of (θi, θr) in degrees.
    pub fn new(theta_i_deg: f64, theta_r_deg: f64) -> PlaneGeometry {
        let psi = 0.5 * (theta_i_deg + theta_r_deg).to_radians();
        let theta_a = 0.5 * (theta_i_deg - theta_r_deg).to_radians();
        let (sin_psi, cos_psi) = psi.sin_cos();
        let cos_psi = cos_psi.max(COS_FLOOR);
        let cos_i = theta_i_deg.to_radians().cos().max(COS_FLOOR);
        let cos_r = theta_r_deg.to_radians().cos().max(COS_FLOOR);
        let cos_a = theta_a.cos();
        // G/(ci·cr) = min(1/(ci·cr), 2ca/(cψ·ci), 2ca/(cψ·cr)): each term stays finite
        // where one cosine vanishes, unlike forming G first and dividing.
        let h = (1.0 / (cos_i * cos_r))
            .min(2.0 * cos_a / (cos_psi * cos_i))
            .min(2.0 * cos_a / (cos_psi * cos_r));
        PlaneGeometry {
            offset_deg: theta_r_deg - theta_i_deg,
            sin2_psi: sin_psi * sin_psi,
            cos_psi,
            attenuation_over_cosines: h,
        }
    }
}

/// Blinn's geometric attenuation G = min(1, 2(n·a)(n·r)/(r·a), 2(n·a)(n·i)/(r·a)).
pub fn geometric_attenuation(theta_i_deg: f64, theta_r_deg: f64) -> f64 {
    let psi = 0.5 * (theta_i_deg + theta_r_deg).to_radians();
    let cos_a = (0.5 * (theta_i_deg - theta_r_deg).to_radians()).cos();
    let cos_psi = psi.cos().max(COS_FLOOR);
    let cos_i = theta_i_deg.to_radians().cos();
    let cos_r = theta_r_deg.to_radians().cos();
    1f64.min(2.0 * cos_a * cos_r / cos_psi).min(2.0 * cos_a * cos_i / cos_psi)
}

/// The paper's Fresnel term F(ψ) and dF/dη, from sin² ψ and cos ψ.
///
/// Written without the 0/0 of the textbook form: with r = η cos δ = sqrt(η² − sin² ψ),
/// sin(ψ−δ)/sin(ψ+δ) = (r − cos ψ)/(r + cos ψ) = (η² − 1)/(r + cos ψ)², and
/// tan(ψ−δ)/tan(ψ+δ) = that × (r cos ψ − sin² ψ)/(r cos ψ + sin² ψ). At ψ = 0 this gives
/// √2 (η−1)/(η+1); at η = 1 it is exactly 0; at ψ + δ = 90° the second factor is 0.
pub fn fresnel_with_derivative(sin2_psi: f64, cos_psi: f64, eta: f64) -> (f64, f64) {
    let eta2_minus_1 = (eta - 1.0) * (eta + 1.0);
    let r2 = eta2_minus_1 + (1.0 - sin2_psi);
    let r = r2.max(0.0).sqrt();
    let c = cos_psi.max(0.0);
    let sum = r + c;
    if sum <= 0.0 {
        // η = 1 and ψ = 90°: the limit along η → 1 is 0.
        return (0.0, 0.0);
    }
    let a = eta2_minus_1 / (sum * sum);
    let cr = c * r;
    let den_b = cr + sin2_psi;
    let b = if den_b > 0.0 { (cr - sin2_psi) / den_b } else { 1.0 };
    let q = (1.0 + b * b).sqrt();
    let f = a * q;
    let dr = if r > 0.0 { eta / r } else { 0.0 };
    let da = 2.0 * eta / (sum * sum) - 2.0 * a / sum * dr;
    let db = if den_b > 0.0 { 2.0 * c * sin2_psi / (den_b * den_b) * dr } else { 0.0 };
    (f, da * q + a * b * db / q)
}

/// F / (η² − 1) and its derivative in η: finite and smooth down to η = 1, where F itself
/// vanishes. The fit uses it with the amplitude ρs·(η² − 1), which the data determine even
/// when η → 1 makes ρs and η separately ill-determined.
pub fn reduced_fresnel_with_derivative(sin2_psi: f64, cos_psi: f64, eta: f64) -> (f64, f64) {
    let r = ((eta - 1.0) * (eta + 1.0) + (1.0 - sin2_psi)).max(0.0).sqrt();
    let c = cos_psi.max(0.0);
    let sum = r + c;
    if sum <= 0.0 {
        return (0.0, 0.0);
    }
    let cr = c * r;
    let den_b = cr + sin2_psi;
    let b = if den_b > 0.0 { (cr - sin2_psi) / den_b } else { 1.0 };
    let q = (1.0 + b * b).sqrt();
    let inv2 = 1.0 / (sum * sum);
    let dr = if r > 0.0 { eta / r } else { 0.0 };
    let db = if den_b > 0.0 { 2.0 * c * sin2_psi / (den_b * den_b) * dr } else { 0.0 };
    (q * inv2, b * db / q * inv2 - 2.0 * q * inv2 / sum * dr)
}

/// The paper's Fresnel term F(ψ) for incidence ψ in degrees.
pub fn fresnel(psi_deg: f64, eta: f64) -> f64 {
    let (s, c) = psi_deg.to_radians().sin_cos();
    fresnel_with_derivative(s * s, c, eta).0
}

/// The lobe exp(−θa²/(2σ²)) with θa = |offset|/2, and its derivative in σ.
///
/// For very small σ the exponential underflows to 0 and so does the derivative
/// (θa²/σ³ · e^(−θa²/2σ²) → 0), never 0 × ∞.
#[inline]
pub fn lobe_with_derivative(offset_deg: f64, sigma_deg: f64) -> (f64, f64) {
    let theta_a = 0.5 * offset_deg.abs();
    if theta_a == 0.0 {
        return (1.0, 0.0);
    }
    let t = theta_a / sigma_deg;
    let e = exp_neg_half_square(t);
    if e == 0.0 { (0.0, 0.0) } else { (e, e * t * t / sigma_deg) }
}

/// exp(−z²/2), returning the 0 that `exp` would give for z² > 1492 (argument below
/// −746) without calling it: the underflowing exponentials take libm's slow path, and
/// they are most of a narrow lobe's points at small σ.
#[inline]
fn exp_neg_half_square(z: f64) -> f64 {
    let z2 = z * z;
    if z2 > 1492.0 { 0.0 } else { (-0.5 * z2).exp() }
}

/// The lobe averaged over a uniform acceptance window of full width `acceptance_deg` in θr,
/// and its derivative in σ. The lobe is a Gaussian of standard deviation 2σ in θr, so its
/// window mean is exact in closed form (erf); F and G/(cos·cos), which change by well
/// under 1 % across a 1° window, are taken at the window's centre.
pub fn windowed_lobe_with_derivative(offset_deg: f64, sigma_deg: f64, acceptance_deg: f64) -> (f64, f64) {
    let w = 2.0 * sigma_deg;
    let half = 0.5 * acceptance_deg;
    let z_hi = (offset_deg + half) / w;
    let z_lo = (offset_deg - half) / w;
    let p = normal_mass(z_lo, z_hi);
    let scale = w * (2.0 * std::f64::consts::PI).sqrt() / acceptance_deg;
    let mean = scale * p;
    let e_hi = exp_neg_half_square(z_hi);
    let e_lo = exp_neg_half_square(z_lo);
    let d = mean / sigma_deg - 2.0 / acceptance_deg * (z_hi * e_hi - z_lo * e_lo);
    (mean, d)
}

/// Φ(hi) − Φ(lo) without cancellation in the tails.
fn normal_mass(lo: f64, hi: f64) -> f64 {
    let k = std::f64::consts::FRAC_1_SQRT_2;
    if lo >= 0.0 {
        0.5 * (libm::erfc(lo * k) - libm::erfc(hi * k))
    } else if hi <= 0.0 {
        0.5 * (libm::erfc(-hi * k) - libm::erfc(-lo * k))
    } else {
        1.0 - 0.5 * libm::erfc(hi * k) - 0.5 * libm::erfc(-lo * k)
    }
}

/// Whether the acceptance window matters for a lobe of this σ (see [`ACCEPTANCE_FWHM_RATIO`]).
pub fn acceptance_matters(sigma_deg: f64, acceptance_deg: f64) -> bool {
    acceptance_deg > 0.0 && FWHM_PER_SIGMA * sigma_deg < ACCEPTANCE_FWHM_RATIO * acceptance_deg
}

/// Radiance factor and its gradient [∂/∂σ (per degree), ∂/∂ρs, ∂/∂ρd, ∂/∂η] at a
/// precomputed geometry; `acceptance_deg` = `Some(a)` averages the lobe over the window.
#[inline]
pub fn evaluate(p: &Params, g: &PlaneGeometry, acceptance_deg: Option<f64>) -> (f64, [f64; 4]) {
    let (e, de) = match acceptance_deg {
        Some(a) if a > 0.0 => windowed_lobe_with_derivative(g.offset_deg, p.sigma_deg, a),
        _ => lobe_with_derivative(g.offset_deg, p.sigma_deg),
    };
    let (f, df) = fresnel_with_derivative(g.sin2_psi, g.cos_psi, p.eta);
    let h = g.attenuation_over_cosines;
    let specular = f * h * e;
    let value = p.rho_s * specular + p.rho_d;
    (value, [p.rho_s * f * h * de, specular, 1.0, p.rho_s * df * h * e])
}

/// Radiance factor of the TSL model at (θi, θr), degrees.
pub fn radiance_factor(p: &Params, theta_i_deg: f64, theta_r_deg: f64) -> f64 {
    evaluate(p, &PlaneGeometry::new(theta_i_deg, theta_r_deg), None).0
}

/// Radiance factor and its analytic gradient [∂/∂σ, ∂/∂ρs, ∂/∂ρd, ∂/∂η].
pub fn radiance_factor_with_gradient(p: &Params, theta_i_deg: f64, theta_r_deg: f64) -> (f64, [f64; 4]) {
    evaluate(p, &PlaneGeometry::new(theta_i_deg, theta_r_deg), None)
}

/// Radiance factor seen by a detector of full acceptance `acceptance_deg` (uniform in θr):
/// the window is modelled only when the lobe is narrow enough for it to matter.
pub fn observed_radiance_factor(p: &Params, theta_i_deg: f64, theta_r_deg: f64, acceptance_deg: f64) -> f64 {
    let window = acceptance_matters(p.sigma_deg, acceptance_deg).then_some(acceptance_deg);
    evaluate(p, &PlaneGeometry::new(theta_i_deg, theta_r_deg), window).0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fresnel_at_normal_incidence_is_the_limit() {
        for eta in [1.0, 1.19, 1.5, 3.0] {
            let expected = std::f64::consts::SQRT_2 * (eta - 1.0) / (eta + 1.0);
            assert!((fresnel(0.0, eta) - expected).abs() < 1e-15);
        }
    }

    #[test]
    fn fresnel_matches_textbook_form_away_from_singularities() {
        for psi in [5.0f64, 20.0, 45.0, 70.0, 85.0] {
            for eta in [1.02, 1.19, 1.5, 3.0] {
                let p = psi.to_radians();
                let d = (p.sin() / eta).asin();
                let t = (p - d).tan() / (p + d).tan();
                let s = (p - d).sin() / (p + d).sin();
                let textbook = (t * t + s * s).sqrt();
                let ours = fresnel(psi, eta);
                assert!((ours - textbook).abs() <= 1e-12 * textbook, "ψ {psi} η {eta}: {ours} vs {textbook}");
            }
        }
    }

    #[test]
    fn windowed_lobe_tends_to_point_lobe_for_tiny_window() {
        for offset in [0.0, 0.7, 2.0] {
            let (e, de) = lobe_with_derivative(offset, 0.8);
            let (m, dm) = windowed_lobe_with_derivative(offset, 0.8, 1e-4);
            assert!((e - m).abs() < 1e-8 && (de - dm).abs() < 1e-6, "{offset}: {e} {m} {de} {dm}");
        }
    }
}
