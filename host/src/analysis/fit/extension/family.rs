//! The nested family: the paper's TSL model as its simplest member, and the terms the data
//! may call for on top of it, each of which reduces to TSL at its null value.
//!
//! Radiance factor at a point (θi, θr), θa = (θr − θi)/2 and ψ = (θi + θr)/2 as in
//! [`crate::analysis::model`]:
//!
//! ```text
//! f = ρs·F(ψ, η)·H·[D(θa; σ_i·(1 ± t), κ) + h·exp(−θa²/(2σh²))] + ρd·exp(b·q)·(1 + B·exp(−|g|/w))
//! σ_i = σ·exp(β·(θi − 45°)/45°),   σh = σ_i·e^u,   q = (1 − cos θi) + (1 − cos θr) − 2(1 − cos 45°)
//! g = θi + θr, the phase angle in the plane (θr < 0 on the source's side: g = 0 is retro-reflection)
//! D(θa; s, κ, μ) = (1 + a·w)^(−(1+κ)/(2κ)),   w = X(θa)²/X(h)²,  h = s·√(2 ln 2),  a = 2^(2κ/(1+κ)) − 1
//! X(θ) = sin(√μ·θ)/√μ (μ > 0),  θ (μ = 0),  θ in radians
//! ```
//!
//! - **lobe shape** (κ ≥ −¼): for κ > 0 a Student-t in θa with ν = 1/κ degrees of
//!   freedom, for κ < 0 its continuation of compact support (Pearson's type II, a lighter
//!   tail than the Gaussian's, as Blinn–Phong and Beckmann lobes have against the
//!   Gaussian of their half width), scaled so that D = ½ at θa = σ·√(2 ln 2) whatever κ
//!   is. So σ keeps the project's convention, the Gaussian of the same half-maximum
//!   width, and the classification tree still applies to it; κ → 0 is the Gaussian
//!   (exp(−θa²/(2σ²))) from either side, κ = 1 the Cauchy, κ ≈ ⅓ close to
//!   Trowbridge–Reitz (GGX). κ = 0 is inside the range, so its test has no boundary;
//! - **the lobe's variable** μ, held at 0 (θa, the paper's) or 1 (sin θa): with κ free at
//!   μ = 1 the lobe is a Student-t (or its compact continuation) in sin θa, which holds
//!   two microfacet distributions exactly: Trowbridge–Reitz (GGX),
//!   α⁴/(α²cos²θa + sin²θa)² = (1 + a·sin²θa/sin²h)^−2, is κ = ⅓; Blinn–Phong's cosⁿθa =
//!   (1 − sin²θa)^(n/2) is κ = −1/(n + 1). Near the peak sin θa ≈ θa, so μ matters only
//!   for broad lobes (to the θa family a GGX MC of σ 43.5° reads as σ 36–37°), where the
//!   readings seldom tell the two variables apart: μ is not a term tested but a member the
//!   intervals cover ([`super`]'s `microfacet_members`). w = 1 at h whatever μ is, so σ
//!   keeps its convention;
//! - **haze lobe** (0 ≤ h ≤ 1, u): a second, broader Gaussian lobe of the same Fresnel
//!   and attenuation, its peak the fraction h of the main lobe's, σh at least 1.5 σ (else
//!   it is the main lobe over again);
//! - **σ varying with θi** (β): the lobe's width at θi = 45° is the reported σ;
//! - **a lobe wider on one side** (t): the main lobe's width σ_i·(1 + t) past its peak
//!   (θa > 0, toward grazing) and σ_i·(1 − t) before it, as forward-scattering fibres make
//!   a paper's lobe. The half-maximum width is the mean of the two sides', so σ keeps the
//!   project's convention. D and its slope are continuous at the peak (both 1 and 0 there
//!   whatever t is), so t = 0 is an interior point and its test regular;
//! - **non-Lambertian body** (b): the diffuse part falls (b < 0, Fresnel transmission,
//!   Oren–Nayar's forward plane) or rises (b > 0) toward grazing in both θi and θr
//!   (reciprocal), ρd being its value at the specular geometry of θi = 45°;
//! - **a body behind a Fresnel interface** (η_b ≥ 1): the diffuse part times the
//!   transmittances T(θi)·T(θr)/T(45°)², T = 1 − R, R = F(θ, η_b)²/2 the unpolarised
//!   reflectance of the paper's F: light scattered under a smooth surface leaves it less
//!   toward grazing (Wolff's diffuse model). η_b = 1 is Lambert (R ≡ 0);
//! - **an opposition surge** (B ≥ 0, w): the body brighter toward retro-reflection, as a
//!   porous or fibrous surface's is where its facets hide their own shadows, B at g = 0
//!   and falling e-fold every w degrees of phase angle: the exponential cusp of the
//!   empirical opposition-effect laws (Kaasalainen's exponential–linear, without its
//!   linear part, which the body's shape term holds). ρd is the body away from it (at
//!   g = 90°, the specular geometry of θi = 45°, the surge is below e^−3 of B);
//! - **off-specular peak** (δp): the main lobe centred at θr = θi + δp, its F and G the
//!   geometry's (a sheet whose facets are tilted in the plane, a cockle);
//! - the **arm offset** δ0 of the base fit, every θr read as θr + δ0, free when the base
//!   fit called for it.
//!
//! Through the detector each reading is the mean over its window ([`model::reading_window`]:
//! the arm's travel and the response's steps) with 5-point Gauss–Legendre across each
//! uniform piece, cut where G switches branch (its kinks, [`model::window_pieces`]):
//! within 1e-7 of the exact mean for lobes of σ ≥ 0.3° seen through a 1° window. The
//! base engine integrates in closed form instead; this family evaluates its null model
//! the same way as its extensions, so their costs compare like with like.
use crate::analysis::model::{self, COS_FLOOR, DetectorResponse, fresnel_with_derivative};

/// ln 2.
const LN_2: f64 = std::f64::consts::LN_2;
/// The θi at which a θi-dependent σ is reported, and the body's reference, degrees.
pub(crate) const REFERENCE_THETA_I_DEG: f64 = 45.0;
/// Within this of κ = 0 the lobe is evaluated as the Gaussian it tends to (the Student-t
/// form loses digits as κ → 0), and ∂D/∂κ is taken from the Gaussian's expansion.
const KAPPA_GAUSSIAN: f64 = 1e-7;
/// Lightest tail the lobe may take: κ = −¼ is a lobe of compact support (zero beyond 2.3
/// half widths, where the Gaussian is still at 2.6 % of its peak), lighter than any
/// microfacet lobe the campaign's shapes hold (Beckmann, Blinn–Phong). Below −⅓ the lobe's
/// slope at its edge would not be continuous.
pub(crate) const KAPPA_MIN: f64 = -0.25;
/// Largest off-specular shift of the main lobe's peak, degrees of θr.
const PEAK_SHIFT_MAX_DEG: f64 = 20.0;
/// Largest |t| of a lobe wider on one side (the sides' widths 1 ± t of their mean).
const ASYMMETRY_MAX: f64 = 0.7;
/// The lobe's variable of the microfacet distributions ([`Param::LobeVariable`]): sin θa.
pub(crate) const MICROFACET_VARIABLE: f64 = 1.0;
/// Largest √μ·θ½ (radians) the sine of the lobe's variable is taken at: short of its turn
/// at π/2, where the half maximum would stop moving with σ.
const LOBE_VARIABLE_Z_MAX: f64 = 1.4;
/// Step of the difference for ∂f/∂δ0, degrees.
const SHIFT_STEP_DEG: f64 = 1e-4;

/// The family's parameters, by index into [`Values`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Param {
    LnSigma = 0,
    RhoS = 1,
    RhoD = 2,
    Eta = 3,
    Shift = 4,
    Kappa = 5,
    HazeFraction = 6,
    HazeLnRatio = 7,
    Slope = 8,
    Body = 9,
    BodyEta = 10,
    PeakShift = 11,
    Asymmetry = 12,
    RetroAmplitude = 13,
    RetroLnWidth = 14,
    LobeVariable = 15,
}

/// Number of [`Param`]s.
pub(crate) const N_FAMILY: usize = 16;

impl Param {
    /// Every parameter in index order.
    #[cfg(test)]
    pub(crate) const ALL: [Param; N_FAMILY] = [
        Param::LnSigma,
        Param::RhoS,
        Param::RhoD,
        Param::Eta,
        Param::Shift,
        Param::Kappa,
        Param::HazeFraction,
        Param::HazeLnRatio,
        Param::Slope,
        Param::Body,
        Param::BodyEta,
        Param::PeakShift,
        Param::Asymmetry,
        Param::RetroAmplitude,
        Param::RetroLnWidth,
        Param::LobeVariable,
    ];

    /// Its range: the base fit's bounds for the TSL four, and for the terms what the
    /// term means (a haze at least 1.5× and at most 30× the main lobe's width; a slope or
    /// body that changes the lobe or the diffuse at most e^±2 over the measured range).
    pub(crate) fn bounds(self) -> (f64, f64) {
        use super::super::{ARM_OFFSET_MAX_DEG, ETA_MAX, ETA_MIN, SIGMA_MAX_DEG, SIGMA_MIN_DEG};
        match self {
            Param::LnSigma => (SIGMA_MIN_DEG.ln(), SIGMA_MAX_DEG.ln()),
            Param::RhoS | Param::RhoD => (0.0, f64::INFINITY),
            // A haze is the weaker lobe: at most the main lobe's peak. Free above, the
            // broad lobe took the sheet's own lobe and the main lobe a narrow bump on it
            // (a J2 with a specular bump was reported σ 0.98° for 17.9°, unflagged).
            Param::HazeFraction => (0.0, 1.0),
            Param::Eta | Param::BodyEta => (ETA_MIN, ETA_MAX),
            Param::Shift => (-ARM_OFFSET_MAX_DEG, ARM_OFFSET_MAX_DEG),
            Param::Kappa => (KAPPA_MIN, 3.0),
            Param::HazeLnRatio => (1.5_f64.ln(), 30.0_f64.ln()),
            Param::Slope => (-2.0, 2.0),
            Param::Body => (-4.0, 4.0),
            // A lobe centred off specular by up to 20° of θr: beyond the arm offset's few
            // degrees, as a tilted or cockled sheet's (the campaign's strongest shift, 0.15
            // of a rough paper's full width at half maximum, is 12°).
            Param::PeakShift => (-PEAK_SHIFT_MAX_DEG, PEAK_SHIFT_MAX_DEG),
            // One side up to 5.7 times the other's width ((1 + t)/(1 − t)): a lobe whose
            // narrow side is still a lobe, not a step.
            Param::Asymmetry => (-ASYMMETRY_MAX, ASYMMETRY_MAX),
            // A surge of up to 10 times the body, over 1° to 30° of phase angle (at 30° it
            // is e^−3 of itself at the specular geometry of 45°, where ρd is read).
            Param::RetroAmplitude => (0.0, 10.0),
            Param::RetroLnWidth => (0.0, 30.0_f64.ln()),
            // Held, never fitted: 0 (θa, the paper's) or 1 (sin θa, the microfacet form).
            Param::LobeVariable => (0.0, MICROFACET_VARIABLE),
        }
    }
}

/// Values of every parameter of the family (the inactive ones at their null values).
pub(crate) type Values = [f64; N_FAMILY];

/// Where a lobe of κ < 0 ends, in half widths at half maximum (infinite for κ ≥ 0).
pub(crate) fn support_half_widths(kappa: f64) -> f64 {
    if kappa >= 0.0 {
        return f64::INFINITY;
    }
    (-1.0 / tail_a(kappa)).sqrt()
}

/// The half-maximum width of the main lobe and its haze together, as the Gaussian's σ of
/// that width (σ's convention), over the main lobe's own σ; and their peak over the main
/// lobe's, 1 + h. None without a haze (h = 0) or where the sum's half maximum is not found.
///
/// Why: a main lobe with a haze and a single lobe whose tail is heavier than any the family
/// holds give the same readings (a half-GGX, half-Gaussian lobe on SG, read at 62
/// geometries, was fitted as a Student-t lobe of σ 1.871° with a haze of 2.4 % at 5.9°,
/// χ² p 0.29, every other member rejected, where its single lobe's half-maximum width is
/// 1.9°). Which one the sheet is the readings cannot say; a haze reports the main lobe's
/// width, a single lobe the sum's. At θi = 45°, where σ is reported; the haze is
/// symmetric about the peak, the main lobe's two sides σ·(1 ± t), and the sum's width the
/// mean of its two sides', as the main lobe's is.
pub(crate) fn whole_lobe_over_main(v: &Values) -> Option<(f64, f64)> {
    let h = v[Param::HazeFraction as usize];
    if !(h > 0.0 && h.is_finite()) {
        return None;
    }
    let sigma = v[Param::LnSigma as usize].exp();
    let haze_sigma = sigma * v[Param::HazeLnRatio as usize].exp();
    let t = v[Param::Asymmetry as usize];
    let tail = Tail::at(v[Param::Kappa as usize]);
    let mu = v[Param::LobeVariable as usize];
    let half = 0.5 * (1.0 + h);
    let side = |s: f64| -> Option<f64> {
        let total = |theta_a: f64| {
            lobe(theta_a, s, tail, mu).0
                + h * (-theta_a * theta_a / (2.0 * haze_sigma * haze_sigma)).exp()
        };
        // The sum falls from 1 + h at the peak; its half is passed within the haze's
        // reach (the haze alone is at h·e^(−½·k²) there).
        let mut hi = s.max(haze_sigma) * 40.0;
        if total(hi) > half {
            return None;
        }
        let mut lo = 0.0;
        for _ in 0..200 {
            let mid = 0.5 * (lo + hi);
            if total(mid) > half {
                lo = mid;
            } else {
                hi = mid;
            }
            if hi - lo <= 1e-12 * s {
                break;
            }
        }
        Some(0.5 * (lo + hi))
    };
    let width = 0.5 * (side(sigma * (1.0 + t))? + side(sigma * (1.0 - t))?);
    let ratio = width / (sigma * (2.0 * LN_2).sqrt());
    (ratio.is_finite() && ratio > 0.0).then_some((ratio, 1.0 + h))
}

/// The tail's a = 2^(2κ/(1+κ)) − 1 (module docs), negative for κ < 0.
#[inline]
fn tail_a(kappa: f64) -> f64 {
    (2.0 * kappa * LN_2 / (1.0 + kappa)).exp_m1()
}

/// D, ∂D/∂ln s, ∂D/∂κ and ∂D/∂θa at θa for a lobe of Gaussian-equivalent width s
/// (degrees), tail `tail` (`None`: the Gaussian) and variable μ.
#[inline]
fn lobe(theta_a_deg: f64, s_deg: f64, tail: Option<Tail>, mu: f64) -> (f64, f64, f64, f64) {
    let (w, w_ln_s, w_theta_a) = lobe_w(theta_a_deg, s_deg, mu);
    let (d, d_w, d_kappa) = match tail {
        // At κ = 0 (κ inactive, or the Gaussian fitted) ∂D/∂κ is the Gaussian's
        // expansion, ln D = −ln2·w + κ·(ln2)²·w·(w − 1) + O(κ²): 0 at the half maximum
        // (w = 1), which κ leaves where it is. The covariance of a member whose κ is free
        // but 0 still holds what κ leaves open.
        None => {
            let d = (-LN_2 * w).exp();
            (d, -LN_2 * d, d * LN_2 * LN_2 * w * (w - 1.0))
        }
        Some(tail) => tail.lobe(w),
    };
    (d, d_w * w_ln_s, d_kappa, d_w * w_theta_a)
}

/// The lobe's w = X(θa)²/X(θ½)² (module docs: X the lobe's variable, θ½ = s·√(2 ln 2) the
/// half-maximum point, so w = 1 there whatever μ is), with ∂w/∂ln s and ∂w/∂θa (per
/// degree).
#[inline]
fn lobe_w(theta_a_deg: f64, s_deg: f64, mu: f64) -> (f64, f64, f64) {
    let half_deg = s_deg * (2.0 * LN_2).sqrt();
    if mu <= 0.0 {
        let r = theta_a_deg / half_deg;
        return (r * r, -2.0 * r * r, 2.0 * r / half_deg);
    }
    // X ∝ sin(√μ·θ) (the 1/√μ cancels in the ratio). A lobe whose half maximum lies near
    // where the sine turns (σ beyond ~68° at μ = 1) keeps the variable of the largest √μ
    // that does not turn: its half maximum still moves with σ.
    let h = half_deg.to_radians();
    let root = mu.sqrt().min(LOBE_VARIABLE_Z_MAX / h);
    let z_a = (root * theta_a_deg.abs().to_radians()).min(std::f64::consts::FRAC_PI_2);
    let (sin_h, cos_h) = (root * h).sin_cos();
    let (sin_a, cos_a) = z_a.sin_cos();
    let r = sin_a / sin_h;
    let w = r * r;
    (
        w,
        -2.0 * w * root * h * cos_h / sin_h,
        2.0 * r * root * cos_a / sin_h * std::f64::consts::PI / 180.0 * theta_a_deg.signum(),
    )
}

/// 1 − cos θ, the body's shape variable's part of one angle (q sums θi's and θr's less
/// twice 45°'s: 0 at θi = θr = 45°).
#[inline]
fn one_minus_cos(theta_deg: f64) -> f64 {
    1.0 - theta_deg.to_radians().cos()
}

/// The transmittance T = 1 − F²/2 of the paper's Fresnel amplitude F at an angle of
/// sine² `sin2` and cosine `cos`, and dT/dη. Within 0.001° of grazing it is taken at
/// 89.999°, where F has a finite slope.
#[inline]
fn transmittance(sin2: f64, cos: f64, eta: f64) -> (f64, f64) {
    let cos_grazing = GRAZING_DEG.to_radians().cos();
    let (sin2, cos) = if cos.abs() < cos_grazing {
        (1.0 - cos_grazing * cos_grazing, cos_grazing)
    } else {
        (sin2, cos.abs())
    };
    let (f, d_f) = fresnel_with_derivative(sin2, cos, eta);
    (1.0 - 0.5 * f * f, -f * d_f)
}

/// Angle the Fresnel body's transmittance is held at nearer grazing, degrees.
const GRAZING_DEG: f64 = 89.999;

/// 5-point Gauss–Legendre on [−½, ½]: offsets and weights.
const GL5: [(f64, f64); 5] = [
    (-0.453_089_922_969_332_2, 0.118_463_442_528_094_5),
    (-0.269_234_655_052_841_4, 0.239_314_335_249_683_2),
    (0.0, 0.284_444_444_444_444_4),
    (0.269_234_655_052_841_4, 0.239_314_335_249_683_2),
    (0.453_089_922_969_332_2, 0.118_463_442_528_094_5),
];

/// Sine and cosine of half an angle in degrees.
#[inline]
fn half_sin_cos(theta_deg: f64) -> (f64, f64) {
    (0.5 * theta_deg).to_radians().sin_cos()
}

/// One reading as the family sees it: its θi's terms, and the nodes it averages over.
///
/// Every angle is kept as the sine and cosine of its half: an arm offset δ0 turns each
/// node's by one rotation (the same for every node of every reading), and ψ, θa and θr's
/// cosines follow from θi's and θr's halves by sums and products. A fit evaluates every
/// reading hundreds of times with δ0 moving; computing the nodes' trigonometry afresh
/// each time was two thirds of a sweep session's fitting.
pub(crate) struct Reading {
    theta_i_deg: f64,
    /// (θi − 45°)/45°, σ's slope variable.
    x_i: f64,
    /// sin(θi/2), cos(θi/2).
    half_i: (f64, f64),
    /// sin² θi and cos θi (the Fresnel body's transmittance).
    sin2_i: f64,
    cos_i: f64,
    nodes: Vec<Node>,
}

/// One node of a reading: its θr without an arm offset, the sine and cosine of its half,
/// and its weight (a reading's weights sum to 1).
struct Node {
    theta_r_deg: f64,
    half_r: (f64, f64),
    weight: f64,
}

/// The terms of the geometry at one node under an arm offset.
struct Geometry {
    theta_r_deg: f64,
    /// θr − θi, degrees.
    offset_deg: f64,
    sin2_psi: f64,
    cos_psi: f64,
    /// G/(cos θi·cos θr), as [`model::PlaneGeometry`] forms it.
    attenuation_over_cosines: f64,
    /// The body's shape variable q.
    q: f64,
    /// sin² θr and cos θr.
    sin2_r: f64,
    cos_r: f64,
}

impl Reading {
    /// The reading at (θi, θr) whose arm moved `span_deg`, through `response`.
    ///
    /// `lobe_sd_deg` is the main lobe's standard deviation in θr (2σ) as the base fit
    /// found it: where everything the detector averages over spans less than a tenth of
    /// it and G has no kink in it, the reading is the mean of the model at two nodes, the
    /// window's mean offset ± its standard deviation (exact for a parabola: within 1e-6 of
    /// the average), which makes a rough paper's sweep of 1,400 bins several times cheaper
    /// to fit; the nodes stay fixed through the fit, so every member is evaluated alike.
    pub(crate) fn new(
        theta_i_deg: f64,
        theta_r_deg: f64,
        span_deg: f64,
        response: Option<&DetectorResponse>,
        lobe_sd_deg: f64,
    ) -> Reading {
        let (window, centres) = model::reading_window(span_deg, response);
        let offsets = centres.iter().map(|(c, _)| *c);
        let extent = offsets.clone().fold(f64::NEG_INFINITY, f64::max)
            - offsets.fold(f64::INFINITY, f64::min)
            + window.unwrap_or(0.0);
        // Each uniform piece of the window, cut where G switches branch: G/(cos θi cos θr)
        // has a kink there, which neither one node nor Gauss–Legendre across the kink
        // averages (the paper's (30°, 70°) and (60°, 0°) lie on kinks: at the window's
        // centre alone, a rough paper's reading at (30°, 70°) came out 0.5 % high, five
        // times its noise, and the family's fits of exact-TSL rough papers missed the
        // readings the base fit matches, σ 0.2 % low).
        let pieces: Vec<(f64, f64, f64)> = match window {
            Some(a) if a > 0.0 => centres
                .iter()
                .flat_map(|&(c, w)| {
                    model::window_pieces(theta_i_deg, theta_r_deg + c, a)
                        .into_iter()
                        .map(move |(mid, width)| (mid - theta_r_deg, width, w * width / a))
                })
                .collect(),
            _ => Vec::new(),
        };
        let kinked = pieces.len() > centres.len();
        let nodes: Vec<(f64, f64)> = match window {
            _ if extent < 0.1 * lobe_sd_deg && !kinked => {
                // The window's mean and variance (each piece uniform over its width).
                let mean = centres.iter().map(|(c, w)| c * w).sum::<f64>();
                let piece_variance = window.map_or(0.0, |a| a * a / 12.0);
                let variance = centres
                    .iter()
                    .map(|(c, w)| w * ((c - mean).powi(2) + piece_variance))
                    .sum::<f64>();
                let sd = variance.max(0.0).sqrt();
                if sd > 0.0 {
                    vec![(mean - sd, 0.5), (mean + sd, 0.5)]
                } else {
                    vec![(mean, 1.0)]
                }
            }
            Some(a) if a > 0.0 => pieces
                .iter()
                .flat_map(|&(mid, width, w)| {
                    GL5.iter().map(move |&(x, g)| (mid + width * x, w * g))
                })
                .collect(),
            _ => centres,
        };
        let (sin_i, cos_i) = theta_i_deg.to_radians().sin_cos();
        Reading {
            theta_i_deg,
            x_i: (theta_i_deg - REFERENCE_THETA_I_DEG) / REFERENCE_THETA_I_DEG,
            half_i: half_sin_cos(theta_i_deg),
            sin2_i: sin_i * sin_i,
            cos_i,
            nodes: nodes
                .into_iter()
                .map(|(offset, weight)| Node {
                    theta_r_deg: theta_r_deg + offset,
                    half_r: half_sin_cos(theta_r_deg + offset),
                    weight,
                })
                .collect(),
        }
    }

    /// The geometry at `node` with the arm offset `shift_deg`, whose half angle's sine and
    /// cosine are `rotation`: the terms of [`model::PlaneGeometry::new`], from the halves.
    #[inline]
    fn geometry(&self, node: &Node, shift_deg: f64, rotation: (f64, f64)) -> Geometry {
        let (s_d, c_d) = rotation;
        let (s_r, c_r) = (
            node.half_r.0 * c_d + node.half_r.1 * s_d,
            node.half_r.1 * c_d - node.half_r.0 * s_d,
        );
        let (s_i, c_i) = self.half_i;
        // ψ = (θi + θr)/2, θa = (θi − θr)/2.
        let sin_psi = s_i * c_r + c_i * s_r;
        let cos_psi_raw = c_i * c_r - s_i * s_r;
        let cos_a = c_i * c_r + s_i * s_r;
        let cos_r_raw = c_r * c_r - s_r * s_r;
        let sin_r = 2.0 * s_r * c_r;
        let cos_psi = cos_psi_raw.max(COS_FLOOR);
        let cos_i = self.cos_i.max(COS_FLOOR);
        let cos_r = cos_r_raw.max(COS_FLOOR);
        // G/(ci·cr) = min(1/(ci·cr), 2ca/(cψ·ci), 2ca/(cψ·cr)), as PlaneGeometry forms it.
        let attenuation_over_cosines = (1.0 / (cos_i * cos_r))
            .min(2.0 * cos_a / (cos_psi * cos_i))
            .min(2.0 * cos_a / (cos_psi * cos_r));
        let theta_r_deg = node.theta_r_deg + shift_deg;
        Geometry {
            theta_r_deg,
            offset_deg: theta_r_deg - self.theta_i_deg,
            sin2_psi: sin_psi * sin_psi,
            cos_psi,
            attenuation_over_cosines,
            q: (1.0 - self.cos_i) + (1.0 - cos_r_raw) - 2.0 * one_minus_cos(REFERENCE_THETA_I_DEG),
            sin2_r: sin_r * sin_r,
            cos_r: cos_r_raw,
        }
    }
}

/// The lobe's tail constants at κ: a, the exponent −(1+κ)/(2κ)'s magnitude, and their
/// derivatives in κ (module docs: D = (1 + a·w)^(−power)); `None` within
/// [`KAPPA_GAUSSIAN`] of 0, where the lobe is the Gaussian.
#[derive(Clone, Copy)]
struct Tail {
    a: f64,
    power: f64,
    d_a: f64,
    d_power: f64,
}

impl Tail {
    fn at(kappa: f64) -> Option<Tail> {
        if kappa.abs() < KAPPA_GAUSSIAN {
            return None;
        }
        let a = tail_a(kappa);
        Some(Tail {
            a,
            power: (1.0 + kappa) / (2.0 * kappa),
            d_a: (a + 1.0) * 2.0 * LN_2 / ((1.0 + kappa) * (1.0 + kappa)),
            d_power: -0.5 / (kappa * kappa),
        })
    }

    /// D, ∂D/∂w and ∂D/∂κ at w = θa²/h².
    #[inline]
    fn lobe(self, w: f64) -> (f64, f64, f64) {
        let base = self.a * w;
        // κ < 0 (a lighter tail than the Gaussian's, Pearson's type II): a < 0, and the
        // lobe is 0 where 1 + a·w ≤ 0.
        if base <= -1.0 {
            return (0.0, 0.0, 0.0);
        }
        let log = base.ln_1p();
        let d = (-self.power * log).exp();
        let d_w = -self.power * self.a / (1.0 + base) * d;
        let d_kappa = -d * (self.d_power * log + self.power * w * self.d_a / (1.0 + base));
        (d, d_w, d_kappa)
    }
}

/// The family at one point of its parameters, with what the evaluation of every reading
/// there shares: the lobe's tail constants, the body's reference transmittance, the arm
/// offset's rotations, and which gradients are asked for.
pub(crate) struct At<'a> {
    v: &'a Values,
    tail: Option<Tail>,
    /// T(45°, η_b) and dT/dη_b there (η_b > 1).
    reference_transmittance: (f64, f64),
    retro_width_deg: f64,
    /// Half the arm offset's sine and cosine, and the same at ± [`SHIFT_STEP_DEG`].
    rotations: [(f64, f64); 3],
    gradient: bool,
    shift_gradient: bool,
    /// The haze's and the surge's terms: evaluated where they are present, and where they
    /// are free even at their null (∂f/∂h at h = 0 is what lets a member whose haze fitted
    /// to nothing still say how much haze the data leave open).
    haze: bool,
    retro: bool,
    kappa_gradient: bool,
    body_eta_gradient: bool,
}

impl<'a> At<'a> {
    /// At `v`, with the gradients over `active` (`None`: the value alone, as a trial
    /// step's cost needs). The gradients of parameters not in `active` may be left 0.
    pub(crate) fn new(v: &'a Values, active: Option<&[Param]>) -> At<'a> {
        let free = |p: &[Param]| active.is_some_and(|a| p.iter().any(|q| a.contains(q)));
        let eta_b = v[Param::BodyEta as usize];
        let reference_transmittance = if eta_b > 1.0 {
            let (s, c) = REFERENCE_THETA_I_DEG.to_radians().sin_cos();
            transmittance(s * s, c, eta_b)
        } else {
            (1.0, 0.0)
        };
        let shift = v[Param::Shift as usize];
        Self {
            v,
            tail: Tail::at(v[Param::Kappa as usize]),
            reference_transmittance,
            retro_width_deg: v[Param::RetroLnWidth as usize].exp(),
            rotations: [0.0, SHIFT_STEP_DEG, -SHIFT_STEP_DEG].map(|d| half_sin_cos(shift + d)),
            gradient: active.is_some(),
            shift_gradient: free(&[Param::Shift]),
            haze: v[Param::HazeFraction as usize] > 0.0
                || free(&[Param::HazeFraction, Param::HazeLnRatio]),
            retro: v[Param::RetroAmplitude as usize] > 0.0
                || free(&[Param::RetroAmplitude, Param::RetroLnWidth]),
            kappa_gradient: free(&[Param::Kappa]),
            body_eta_gradient: free(&[Param::BodyEta]) && eta_b > 1.0,
        }
    }

    /// The reading's model value and its gradient (all 0 without gradients); ∂/∂δ0 by
    /// central difference.
    pub(crate) fn evaluate(&self, reading: &Reading) -> (f64, Values) {
        let v = self.v;
        let shift = v[Param::Shift as usize];
        let ln_s = v[Param::LnSigma as usize] + v[Param::Slope as usize] * reading.x_i;
        let per_reading = PerReading {
            s: ln_s.exp(),
            haze_s: if self.haze {
                (ln_s + v[Param::HazeLnRatio as usize]).exp()
            } else {
                0.0
            },
            transmittance_i: if v[Param::BodyEta as usize] > 1.0 {
                transmittance(reading.sin2_i, reading.cos_i, v[Param::BodyEta as usize])
            } else {
                (1.0, 0.0)
            },
        };
        let (mut value, mut grad) = (0.0, [0.0; N_FAMILY]);
        let (mut plus, mut minus) = (0.0, 0.0);
        for node in &reading.nodes {
            let geometry = reading.geometry(node, shift, self.rotations[0]);
            let (f, g) = self.point(reading, &per_reading, &geometry, self.gradient);
            value += node.weight * f;
            if self.gradient {
                for (t, gi) in grad.iter_mut().zip(g) {
                    *t += node.weight * gi;
                }
            }
            if self.shift_gradient {
                for (sum, k, d) in [
                    (&mut plus, 1, SHIFT_STEP_DEG),
                    (&mut minus, 2, -SHIFT_STEP_DEG),
                ] {
                    let moved = reading.geometry(node, shift + d, self.rotations[k]);
                    *sum += node.weight * self.point(reading, &per_reading, &moved, false).0;
                }
            }
        }
        if self.shift_gradient {
            grad[Param::Shift as usize] = (plus - minus) / (2.0 * SHIFT_STEP_DEG);
        }
        (value, grad)
    }

    /// The reading's model value alone.
    pub(crate) fn value(&self, reading: &Reading) -> f64 {
        self.evaluate(reading).0
    }

    /// The point model's value and its gradient over every [`Param`] (∂/∂δ0 left 0: it is
    /// taken by difference over the whole reading).
    #[inline]
    fn point(
        &self,
        reading: &Reading,
        per_reading: &PerReading,
        g: &Geometry,
        gradient: bool,
    ) -> (f64, Values) {
        let v = self.v;
        let (theta_i_deg, theta_r_deg) = (reading.theta_i_deg, g.theta_r_deg);
        // An off-specular peak moves the main lobe alone (its F and G stay the geometry's).
        let theta_a = 0.5 * (g.offset_deg - v[Param::PeakShift as usize]);
        // A lobe wider on one side: the side's width, the mean of the two the lobe's σ.
        let side = if theta_a > 0.0 {
            1.0
        } else if theta_a < 0.0 {
            -1.0
        } else {
            0.0
        };
        let side_factor = 1.0 + v[Param::Asymmetry as usize] * side;
        let s = per_reading.s * side_factor;
        let (d, d_ln_s, d_kappa, d_theta_a) =
            lobe(theta_a, s, self.tail, v[Param::LobeVariable as usize]);
        let (fr, d_fr) = fresnel_with_derivative(g.sin2_psi, g.cos_psi, v[Param::Eta as usize]);
        let h = g.attenuation_over_cosines;
        let (rho_s, rho_d, haze_fraction) = (
            v[Param::RhoS as usize],
            v[Param::RhoD as usize],
            v[Param::HazeFraction as usize],
        );
        let rho_h = rho_s * haze_fraction;
        // A value alone needs the haze only where there is one.
        let (dh, dh_ln) = if rho_h > 0.0 || (gradient && self.haze) {
            // The haze stays about specular: a shift is the main lobe's term.
            let z = 0.5 * g.offset_deg / per_reading.haze_s;
            let e = (-0.5 * z * z).exp();
            (e, e * z * z)
        } else {
            (0.0, 0.0)
        };
        let eta_b = v[Param::BodyEta as usize];
        let (transmitted, d_transmitted) = if eta_b > 1.0 {
            let (t_i, d_t_i) = per_reading.transmittance_i;
            let (t_r, d_t_r) = transmittance(g.sin2_r, g.cos_r, eta_b);
            let (t_0, d_t_0) = self.reference_transmittance;
            let ratio = t_i * t_r / (t_0 * t_0);
            let derivative = if self.body_eta_gradient {
                ratio * (d_t_i / t_i + d_t_r / t_r - 2.0 * d_t_0 / t_0)
            } else {
                0.0
            };
            (ratio, derivative)
        } else {
            (1.0, 0.0)
        };
        let b = v[Param::Body as usize];
        let shape = if b == 0.0 { 1.0 } else { (b * g.q).exp() };
        let retro_b = v[Param::RetroAmplitude as usize];
        let (cusp, d_cusp_ln_w) = if retro_b > 0.0 || (gradient && self.retro) {
            let per_width = (theta_i_deg + theta_r_deg).abs() / self.retro_width_deg;
            let e = (-per_width).exp();
            (e, e * per_width)
        } else {
            (0.0, 0.0)
        };
        let surge = 1.0 + retro_b * cusp;
        let body_without_surge = shape * transmitted;
        let body = body_without_surge * surge;
        let fh = fr * h;
        let value = rho_s * fh * d + rho_h * fh * dh + rho_d * body;
        if !gradient {
            return (value, [0.0; N_FAMILY]);
        }
        let d_ln = rho_s * fh * d_ln_s + rho_h * fh * dh_ln;
        let mut grad = [0.0; N_FAMILY];
        grad[Param::LnSigma as usize] = d_ln;
        grad[Param::RhoS as usize] = fh * (d + haze_fraction * dh);
        grad[Param::RhoD as usize] = body;
        grad[Param::Eta as usize] = (rho_s * d + rho_h * dh) * h * d_fr;
        if self.kappa_gradient {
            grad[Param::Kappa as usize] = rho_s * fh * d_kappa;
        }
        grad[Param::HazeFraction as usize] = rho_s * fh * dh;
        grad[Param::HazeLnRatio as usize] = rho_h * fh * dh_ln;
        grad[Param::Slope as usize] = d_ln * reading.x_i;
        grad[Param::Body as usize] = rho_d * body * g.q;
        grad[Param::BodyEta as usize] = rho_d * shape * surge * d_transmitted;
        grad[Param::RetroAmplitude as usize] = rho_d * body_without_surge * cusp;
        grad[Param::RetroLnWidth as usize] = rho_d * body_without_surge * retro_b * d_cusp_ln_w;
        // θa = (θr − θi − δp)/2.
        grad[Param::PeakShift as usize] = -0.5 * rho_s * fh * d_theta_a;
        // The side's ln width moves by side/(1 + t·side) per unit of t.
        grad[Param::Asymmetry as usize] = rho_s * fh * d_ln_s * side / side_factor;
        (value, grad)
    }
}

/// What a reading's nodes share at one point of the parameters.
struct PerReading {
    /// The main lobe's width at the reading's θi, σ·exp(β·x_i), before the side's factor.
    s: f64,
    /// The haze's width there (0 where the haze is not evaluated).
    haze_s: f64,
    /// T(θi, η_b) and dT/dη_b.
    transmittance_i: (f64, f64),
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::model::{Params, evaluate_reading_through};

    fn tail_lobe(theta_a_deg: f64, s_deg: f64, kappa: f64) -> (f64, f64, f64, f64) {
        lobe(theta_a_deg, s_deg, Tail::at(kappa), 0.0)
    }

    /// The reading's value and, with `gradients`, its gradient over every parameter.
    fn evaluate(v: &Values, reading: &Reading, gradients: bool) -> (f64, Values) {
        At::new(v, gradients.then_some(&Param::ALL[..])).evaluate(reading)
    }

    fn tsl(sigma_deg: f64) -> Values {
        let mut v = [0.0; N_FAMILY];
        v[Param::LnSigma as usize] = sigma_deg.ln();
        v[Param::RhoS as usize] = 0.8;
        v[Param::RhoD as usize] = 0.85;
        v[Param::Eta as usize] = 1.5;
        v[Param::BodyEta as usize] = 1.0;
        v[Param::HazeLnRatio as usize] = 3.0_f64.ln();
        v
    }

    /// The sum's half maximum is where the sum is half its peak, on either side; a haze
    /// as wide as the main lobe leaves the width alone; no haze, no alternative.
    #[test]
    fn the_whole_lobes_width_is_where_the_sum_falls_to_half_its_peak() {
        assert_eq!(whole_lobe_over_main(&tsl(2.0)), None);
        for (sigma, h, haze_ratio, t) in [
            (2.0, 0.03, 3.0, 0.0),
            (1.9, 0.2, 1.5, 0.0),
            (17.0, 0.5, 4.0, 0.3),
            (0.8, 1.0, 30.0, -0.2),
        ] {
            let mut v = tsl(sigma);
            v[Param::HazeFraction as usize] = h;
            v[Param::HazeLnRatio as usize] = f64::ln(haze_ratio);
            v[Param::Asymmetry as usize] = t;
            let (ratio, peak) = whole_lobe_over_main(&v).unwrap();
            assert_eq!(peak, 1.0 + h);
            assert!(ratio > 1.0, "{ratio}");
            // Each side's half point, written out for the Gaussian: the sides' mean is
            // the sum's half width, each side where the sum is (1 + h)/2.
            let haze_sigma = sigma * haze_ratio;
            let sum = |x: f64, s: f64| {
                (-x * x / (2.0 * s * s)).exp()
                    + h * (-x * x / (2.0 * haze_sigma * haze_sigma)).exp()
            };
            let half_width = ratio * sigma * (2.0 * LN_2).sqrt();
            // With t = 0 both sides are the same point.
            if t == 0.0 {
                assert!((sum(half_width, sigma) - 0.5 * (1.0 + h)).abs() < 1e-9);
            } else {
                let root = |s: f64| {
                    let (mut lo, mut hi) = (0.0, 100.0 * haze_sigma);
                    for _ in 0..200 {
                        let mid = 0.5 * (lo + hi);
                        if sum(mid, s) > 0.5 * (1.0 + h) {
                            lo = mid
                        } else {
                            hi = mid
                        }
                    }
                    lo
                };
                let mean = 0.5 * (root(sigma * (1.0 + t)) + root(sigma * (1.0 - t)));
                assert!(
                    (mean / half_width - 1.0).abs() < 1e-9,
                    "{mean} {half_width}"
                );
            }
        }
        // A haze as wide as the main lobe is the same Gaussian, h higher.
        let mut v = tsl(3.0);
        v[Param::HazeFraction as usize] = 0.4;
        v[Param::HazeLnRatio as usize] = 0.0;
        let (ratio, _) = whole_lobe_over_main(&v).unwrap();
        assert!((ratio - 1.0).abs() < 1e-9, "{ratio}");
        // The case in the function's docs: a half-GGX, half-Gaussian lobe of σ 1.9° on SG
        // fitted as a Student-t of σ 1.871° (κ 0.15) with a haze of 2.4 % at 5.9°. The
        // sum's width is the sheet's.
        let mut v = tsl(1.871);
        v[Param::Kappa as usize] = 0.15;
        v[Param::HazeFraction as usize] = 0.024;
        v[Param::HazeLnRatio as usize] = f64::ln(5.9 / 1.871);
        let (ratio, _) = whole_lobe_over_main(&v).unwrap();
        let whole = 1.871 * ratio;
        assert!((whole - 1.9).abs() < 0.01, "{whole}");
    }

    #[test]
    fn the_null_member_is_the_tsl_model_through_the_window() {
        let response = DetectorResponse::top_hat(1.0);
        for sigma in [0.8, 3.0, 12.0] {
            let v = tsl(sigma);
            let p = Params {
                sigma_deg: sigma,
                rho_s: 0.8,
                rho_d: 0.85,
                eta: 1.5,
            };
            for (ti, tr, span) in [(45.0, 45.3, 0.0), (20.0, 23.0, 0.4), (60.0, 10.0, 0.0)] {
                let reading = Reading::new(ti, tr, span, Some(&response), 0.0);
                let ours = evaluate(&v, &reading, false).0;
                let theirs = evaluate_reading_through(&p, ti, tr, span, Some(&response)).0;
                assert!(
                    ((ours - theirs) / theirs).abs() < 1e-6,
                    "σ {sigma} at ({ti}, {tr}): {ours} against {theirs}"
                );
            }
        }
    }

    /// The paper's twelve geometries on a rough paper, each reading at the lobe's width
    /// the fit passes (2σ, the one-node shortcut's test): (30°, 70°) and (60°, 0°) lie on
    /// kinks of G, where the window's mean is not the model at its centre (0.5 % apart at
    /// (30°, 70°) on J2, five times a reading's noise).
    #[test]
    fn the_null_member_averages_across_the_kinks_of_g() {
        let response = DetectorResponse::top_hat(1.0);
        let p = Params {
            sigma_deg: 17.9,
            rho_s: 0.73,
            rho_d: 0.058,
            eta: 3.0,
        };
        let mut v = tsl(p.sigma_deg);
        v[Param::RhoS as usize] = p.rho_s;
        v[Param::RhoD as usize] = p.rho_d;
        v[Param::Eta as usize] = p.eta;
        let schedule = protocol::schedules::strategy1(12).expect("M = 12");
        assert!(
            schedule
                .iter()
                .any(|g| (g.theta_i.deg(), g.theta_r.deg()) == (30.0, 70.0))
        );
        for (ti, tr) in schedule.iter().map(|g| (g.theta_i.deg(), g.theta_r.deg())) {
            for span in [0.0, 0.4] {
                let reading = Reading::new(ti, tr, span, Some(&response), 2.0 * p.sigma_deg);
                let ours = evaluate(&v, &reading, false).0;
                let theirs = evaluate_reading_through(&p, ti, tr, span, Some(&response)).0;
                assert!(
                    ((ours - theirs) / theirs).abs() < 1e-6,
                    "({ti}, {tr}) span {span}: {ours} against {theirs}"
                );
            }
        }
    }

    #[test]
    fn sigma_is_the_half_maximum_width_whatever_the_tail() {
        let hwhm = 2.0 * (2.0 * LN_2).sqrt();
        for kappa in [KAPPA_MIN, -0.1, 0.0, 1e-3, 0.33, 1.0, 3.0] {
            let (d, ..) = tail_lobe(hwhm, 2.0, kappa);
            assert!((d - 0.5).abs() < 1e-12, "κ {kappa}: {d}");
        }
        // κ = 1 is the Cauchy of that half width.
        let (d, ..) = tail_lobe(3.0, 2.0, 1.0);
        assert!((d - 1.0 / (1.0 + (3.0 / hwhm).powi(2))).abs() < 1e-12);
    }

    /// At μ = 1 the lobe is the simulator's microfacet lobes exactly (hil-sim's sheet.rs
    /// writes them in θa, with the Gaussian's half-maximum point): GGX, α⁴/(α²cos²θa +
    /// sin²θa)² with sin²θ½ = α²(√2 − 1)/(1 − α²), is κ = ⅓; Blinn–Phong's cosⁿθa with
    /// cosⁿθ½ = ½ is κ = −1/(n + 1). At any μ the half maximum stays at θ½.
    #[test]
    fn the_lobes_variable_holds_ggx_and_blinn_phong() {
        for sigma in [1.9, 17.9, 43.5] {
            let half = sigma * (2.0 * LN_2).sqrt();
            let s = half.to_radians().sin().powi(2);
            let alpha2 = s / (s + std::f64::consts::SQRT_2 - 1.0);
            let n = -LN_2 / half.to_radians().cos().ln();
            for theta_a in [0.0, 0.3 * half, half, 1.7 * half, 60.0_f64.min(3.0 * half)] {
                let (sin, cos) = theta_a.to_radians().sin_cos();
                let ggx = alpha2 * alpha2 / (alpha2 * cos * cos + sin * sin).powi(2);
                let ours = lobe(theta_a, sigma, Tail::at(1.0 / 3.0), 1.0).0;
                assert!(
                    (ours - ggx).abs() < 1e-12,
                    "GGX σ {sigma} at {theta_a}: {ours} against {ggx}"
                );
                let blinn_phong = cos.powf(n);
                let ours = lobe(theta_a, sigma, Tail::at(-1.0 / (n + 1.0)), 1.0).0;
                assert!(
                    (ours - blinn_phong).abs() < 1e-12,
                    "Blinn–Phong σ {sigma} at {theta_a}: {ours} against {blinn_phong}"
                );
            }
            for mu in [0.0, 0.5, MICROFACET_VARIABLE] {
                for kappa in [0.0, 0.3, -0.2] {
                    let d = lobe(half, sigma, Tail::at(kappa), mu).0;
                    assert!((d - 0.5).abs() < 1e-12, "σ {sigma}, μ {mu}, κ {kappa}: {d}");
                }
            }
        }
        // The broad Gaussian in θa is not the broad one in sin θa: μ is what tells them
        // apart, and only where the lobe is broad.
        let wide = |mu: f64| lobe(60.0, 43.5, None, mu).0;
        assert!(
            (wide(1.0) / wide(0.0) - 1.0).abs() > 0.05,
            "{} {}",
            wide(1.0),
            wide(0.0)
        );
        let narrow = |mu: f64| lobe(3.0, 1.9, None, mu).0;
        assert!((narrow(1.0) / narrow(0.0) - 1.0).abs() < 1e-3);
    }

    /// The θa family holds a glossy Beckmann lobe (hil-sim's exp(−tan²θa/α²)/cos⁴θa with
    /// the Gaussian's half-maximum point) with κ a little below 0: on SG (σ 1.9°) κ ≈
    /// −0.0015 matches it to about 10⁻⁶ of the peak where the paper's Gaussian misses it
    /// by 5·10⁻⁴, which swept readings see (the Gaussian puts σ 0.2 % low; the lobe
    /// shape's member recovers 1.9°, docs/ACCURACY.md). No other variable is needed for
    /// it: a Gaussian in sinh(√2·θa)/√2, which follows tan θa to third order, matches it
    /// to 3·10⁻⁶ at σ 1.9° (computed once, not a case here), no closer.
    #[test]
    fn the_lobe_shape_holds_a_glossy_beckmann_lobe() {
        for (sigma, fits_within, kappa_range) in
            [(0.8, 1e-7, (-0.0005, 0.0)), (1.9, 3e-6, (-0.002, -0.001))]
        {
            let half = (sigma * (2.0 * LN_2).sqrt()).to_radians();
            let alpha2 = half.tan().powi(2) / (LN_2 - 4.0 * half.cos().ln());
            let beckmann = |theta_a: f64| {
                let (sin, cos) = theta_a.to_radians().sin_cos();
                (-(sin / cos).powi(2) / alpha2).exp() / cos.powi(4)
            };
            let worst = |kappa: f64| {
                (0..=90)
                    .map(|k| 3.0 * sigma * f64::from(k) / 90.0)
                    .map(|t| (lobe(t, sigma, Tail::at(kappa), 0.0).0 - beckmann(t)).abs())
                    .fold(0.0, f64::max)
            };
            let (best, kappa) = (-500..=500)
                .map(|k| f64::from(k) * 1e-5)
                .map(|kappa| (worst(kappa), kappa))
                .min_by(|a, b| a.0.total_cmp(&b.0))
                .expect("a grid");
            assert!(
                best < fits_within,
                "σ {sigma}: best κ {kappa} misses by {best}"
            );
            assert!(
                kappa >= kappa_range.0 && kappa <= kappa_range.1,
                "σ {sigma}: κ {kappa}"
            );
            assert!(
                worst(0.0) > 50.0 * best,
                "σ {sigma}: the Gaussian {}",
                worst(0.0)
            );
        }
    }

    #[test]
    fn gradients_match_differences() {
        // κ = 0: the Gaussian's expansion; κ < 0: the compact lobe; in θa and in sin θa.
        for (kappa, mu) in [
            (0.4, 0.0),
            (0.0, 0.0),
            (-0.15, 0.0),
            (0.3, 1.0),
            (-0.1, 1.0),
        ] {
            gradients_match_differences_at(kappa, mu);
        }
    }

    fn gradients_match_differences_at(kappa: f64, mu: f64) {
        let mut v = tsl(4.0);
        v[Param::Kappa as usize] = kappa;
        v[Param::LobeVariable as usize] = mu;
        v[Param::HazeFraction as usize] = 0.3;
        v[Param::Slope as usize] = 0.2;
        v[Param::Body as usize] = -0.3;
        v[Param::BodyEta as usize] = 1.4;
        v[Param::Shift as usize] = 0.2;
        v[Param::PeakShift as usize] = 1.3;
        v[Param::Asymmetry as usize] = 0.25;
        v[Param::RetroAmplitude as usize] = 0.6;
        v[Param::RetroLnWidth as usize] = 12.0_f64.ln();
        // Past the peak and before it (the sides of a lobe wider on one side), and a broad
        // lobe far out on both sides, where μ matters.
        for (sigma, theta_r) in [(4.0, 34.0), (4.0, 27.0), (30.0, 80.0), (30.0, -10.0)] {
            v[Param::LnSigma as usize] = f64::ln(sigma);
            let reading = Reading::new(
                30.0,
                theta_r,
                0.3,
                Some(&DetectorResponse::top_hat(1.0)),
                0.0,
            );
            gradients_match_differences_on(&v, &reading, kappa);
        }
    }

    fn gradients_match_differences_on(v: &Values, reading: &Reading, kappa: f64) {
        let v = *v;
        let (_, grad) = evaluate(&v, reading, true);
        for p in Param::ALL {
            let k = p as usize;
            // κ's step leaves the Gaussian's branch (|κ| < 1e-7) on both sides. μ is held,
            // never fitted: its gradient is not formed.
            if p == Param::LobeVariable {
                continue;
            }
            let step = if p == Param::Kappa {
                1e-4
            } else {
                1e-6 * v[k].abs().max(1e-3)
            };
            let (mut up, mut down) = (v, v);
            up[k] += step;
            down[k] -= step;
            let numeric = (evaluate(&up, reading, false).0 - evaluate(&down, reading, false).0)
                / (2.0 * step);
            assert!(
                (numeric - grad[k]).abs() <= 1e-4 * numeric.abs().max(1e-3),
                "κ {kappa}, {p:?}: {} against {numeric}",
                grad[k]
            );
        }
    }
}
