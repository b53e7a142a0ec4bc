//! The Torrance–Sparrow + Lambert (TSL) reflectance model in the specular plane
//! (Akao et al., Eq. 1–4), its analytic derivatives, and the detector's angular acceptance.
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
//!
//! The detector sees the model averaged over its acceptance, a uniform window of full
//! width a in θr. The whole model is averaged, not only the lobe: across the window the
//! slowly varying factor u(θr) = F(ψ)·G/(cos θi cos θr) is replaced by the parabola
//! through its values at the window's centre and edges, and the lobe, a Gaussian in θr,
//! is integrated against 1, s, s² in closed form (truncated-Gaussian moments, erf). Where
//! G has a kink inside the window (the onset of masking or shadowing, e.g. θi = 20° near
//! θr = 66.5°) the window is split there and each piece gets its own parabola. The
//! parabola's error is of order u'''·a³/100, about 1e-6 of the reading for a 1° window at
//! θr ≤ 70° (host/tests/it/model.rs checks it against dense quadrature). It is always done when
//! a window is given: there is no threshold at which the estimator changes.

use serde::Serialize;

/// Full width of the detector's angular acceptance in θr, degrees (the reference instrument).
pub const DEFAULT_ACCEPTANCE_DEG: f64 = 1.0;

/// FWHM of the TS lobe in θr per degree of σ: the lobe has standard deviation 2σ in θr.
pub(crate) const FWHM_PER_SIGMA: f64 = 4.0 * 1.177_410_022_515_474_6; // 4·sqrt(2 ln 2)

/// Index of σ in gradient arrays.
pub const SIGMA: usize = 0;
/// Index of ρs in gradient arrays.
pub const RHO_S: usize = 1;
/// Index of ρd in gradient arrays.
pub const RHO_D: usize = 2;
/// Index of η in gradient arrays.
pub const ETA: usize = 3;
/// Parameter names in gradient order, as every JSON output spells them: the key of the
/// value (`sigma_deg`: σ is in degrees there), of its interval in `ci95`, in `model`,
/// `not_identified`, `active_bounds` and the uncertainty budget.
pub const PARAM_NAMES: [&str; 4] = ["sigma_deg", "rho_s", "rho_d", "eta"];

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
        Params {
            sigma_deg: a[SIGMA],
            rho_s: a[RHO_S],
            rho_d: a[RHO_D],
            eta: a[ETA],
        }
    }
}

/// Smallest cosine used; keeps exactly-grazing geometries finite, and products of two
/// inverse cosines (1e30 at most) too, so that a detector window reaching past 90° gives
/// large but finite terms, never ∞ · 0.
pub(crate) const COS_FLOOR: f64 = 1e-15;

/// The parts of the model that depend only on the geometry.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlaneGeometry {
    /// θi, degrees.
    pub theta_i_deg: f64,
    /// θr, degrees.
    pub theta_r_deg: f64,
    /// θr − θi, degrees (the lobe's coordinate; θa = |offset| / 2).
    pub(crate) offset_deg: f64,
    /// sin² ψ.
    pub(crate) sin2_psi: f64,
    /// cos ψ.
    pub(crate) cos_psi: f64,
    /// G / (cos θi · cos θr).
    pub attenuation_over_cosines: f64,
    /// Which of its three terms it is (see [`attenuation_branch`]).
    pub(crate) attenuation_branch: u8,
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
        let terms = [
            1.0 / (cos_i * cos_r),
            2.0 * cos_a / (cos_psi * cos_i),
            2.0 * cos_a / (cos_psi * cos_r),
        ];
        let mut branch = 0;
        for k in 1..3 {
            if terms[k] < terms[branch] {
                branch = k;
            }
        }
        let h = terms[branch];
        PlaneGeometry {
            attenuation_branch: branch as u8,
            theta_i_deg,
            theta_r_deg,
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
    1f64.min(2.0 * cos_a * cos_r / cos_psi)
        .min(2.0 * cos_a * cos_i / cos_psi)
}

/// The paper's Fresnel term F(ψ) and dF/dη, from sin² ψ and cos ψ.
///
/// Written without the 0/0 of the textbook form: with r = η cos δ = sqrt(η² − sin² ψ),
/// sin(ψ−δ)/sin(ψ+δ) = (r − cos ψ)/(r + cos ψ) = (η² − 1)/(r + cos ψ)², and
/// tan(ψ−δ)/tan(ψ+δ) = that × (r cos ψ − sin² ψ)/(r cos ψ + sin² ψ). At ψ = 0 this gives
/// √2 (η−1)/(η+1); at η = 1 it is exactly 0; at ψ + δ = 90° the second factor is 0.
pub(crate) fn fresnel_with_derivative(sin2_psi: f64, cos_psi: f64, eta: f64) -> (f64, f64) {
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
    let b = if den_b > 0.0 {
        (cr - sin2_psi) / den_b
    } else {
        1.0
    };
    let q = (1.0 + b * b).sqrt();
    let f = a * q;
    let dr = if r > 0.0 { eta / r } else { 0.0 };
    let da = 2.0 * eta / (sum * sum) - 2.0 * a / sum * dr;
    let db = if den_b > 0.0 {
        2.0 * c * sin2_psi / (den_b * den_b) * dr
    } else {
        0.0
    };
    (f, da * q + a * b * db / q)
}

/// F / (η² − 1) and its derivative in η: finite and smooth down to η = 1, where F itself
/// vanishes. The fit uses it with the amplitude ρs·(η² − 1), which the data determine even
/// when η → 1 makes ρs and η separately ill-determined.
pub(crate) fn reduced_fresnel_with_derivative(sin2_psi: f64, cos_psi: f64, eta: f64) -> (f64, f64) {
    let r = ((eta - 1.0) * (eta + 1.0) + (1.0 - sin2_psi))
        .max(0.0)
        .sqrt();
    let c = cos_psi.max(0.0);
    let sum = r + c;
    if sum <= 0.0 {
        return (0.0, 0.0);
    }
    let cr = c * r;
    let den_b = cr + sin2_psi;
    let b = if den_b > 0.0 {
        (cr - sin2_psi) / den_b
    } else {
        1.0
    };
    let q = (1.0 + b * b).sqrt();
    let inv2 = 1.0 / (sum * sum);
    let dr = if r > 0.0 { eta / r } else { 0.0 };
    let db = if den_b > 0.0 {
        2.0 * c * sin2_psi / (den_b * den_b) * dr
    } else {
        0.0
    };
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
pub(crate) fn lobe_with_derivative(offset_deg: f64, sigma_deg: f64) -> (f64, f64) {
    let theta_a = 0.5 * offset_deg.abs();
    if theta_a == 0.0 {
        return (1.0, 0.0);
    }
    let t = theta_a / sigma_deg;
    let e = exp_neg_half_square(t);
    if e == 0.0 {
        (0.0, 0.0)
    } else {
        (e, e * t * t / sigma_deg)
    }
}

/// exp(−z²/2), returning the 0 that `exp` would give for z² > 1492 (argument below
/// −746) without calling it: the underflowing exponentials take libm's slow path, and
/// they are most of a narrow lobe's points at small σ.
#[inline]
fn exp_neg_half_square(z: f64) -> f64 {
    let z2 = z * z;
    if z2 > 1492.0 { 0.0 } else { (-0.5 * z2).exp() }
}

/// The lobe alone averaged over a uniform acceptance window of full width `acceptance_deg`
/// in θr, and its derivative in σ: the window moment M0 of [`window_moments`], exact in
/// closed form (erf). The fit's seeding grid uses it with F and G/(cos·cos) taken at the
/// window's centre; the model itself integrates the whole product ([`evaluate`]).
pub fn windowed_lobe_with_derivative(
    offset_deg: f64,
    sigma_deg: f64,
    acceptance_deg: f64,
) -> (f64, f64) {
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

/// The lobe's moments over the window: with s = θr' − θr the position in the window and
/// L the lobe exp(−(offset + s)²/(2(2σ)²)),
/// `m[k]` = (1/a) ∫ s^k L ds over s ∈ \[−a/2, a/2\] (k = 0, 1, 2) and `dm_dsigma[k]` = ∂m\[k\]/∂σ.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct WindowMoments {
    /// M0, M1 (degrees), M2 (deg²).
    pub m: [f64; 3],
    /// Their derivatives in σ (per degree).
    pub(crate) dm_dsigma: [f64; 3],
}

/// Gauss–Legendre nodes on [−1, 1] (positive half) and weights, 10 points.
const GL10_NODES: [f64; 5] = [
    0.148_874_338_981_631_2,
    0.433_395_394_129_247_2,
    0.679_409_568_299_024_4,
    0.865_063_366_688_984_5,
    0.973_906_528_517_171_7,
];
const GL10_WEIGHTS: [f64; 5] = [
    0.295_524_224_714_752_9,
    0.269_266_719_309_996_3,
    0.219_086_362_515_982,
    0.149_451_349_150_580_6,
    0.066_671_344_308_688_1,
];
/// Gauss–Legendre nodes on [−1, 1] (non-negative half, 0 counted once) and weights, 5 points.
const GL5_NODES: [f64; 3] = [0.0, 0.538_469_310_105_683_1, 0.906_179_845_938_664];
const GL5_WEIGHTS: [f64; 3] = [
    0.568_888_888_888_888_9,
    0.478_628_670_499_366_5,
    0.236_926_885_056_189_1,
];

/// The lobe's window moments ([`WindowMoments`]) for a window of full width `acceptance_deg`.
///
/// Two evaluations of the same integrals, each where it is accurate (both to 1e-9 or
/// better, so the choice never shows in a fit; the unit test checks them against dense
/// quadrature on either side of each switch): a lobe at most four windows wide (w = 2σ <
/// 4a) by the closed form (from integrating by parts, with o the offset, the recurrence
/// M_{n+1} = −o·M_n + (w²/a)[(−a/2)^n L(o−a/2) − (a/2)^n L(o+a/2)] + n·w²·M_{n−1},
/// whose cancellation grows as (2w/a)² per order, ≤ 64 here); a broader one by
/// Gauss–Legendre (5 points where it changes by at most an e-fold across the window, 10
/// where it changes faster).
pub(crate) fn window_moments(
    offset_deg: f64,
    sigma_deg: f64,
    acceptance_deg: f64,
) -> WindowMoments {
    let w = 2.0 * sigma_deg;
    let a = acceptance_deg;
    let h = 0.5 * a;
    let o = offset_deg;
    let mut m = [0.0; 5];
    if w < 4.0 * a {
        let (z_lo, z_hi) = ((o - h) / w, (o + h) / w);
        let (l_lo, l_hi) = (exp_neg_half_square(z_lo), exp_neg_half_square(z_hi));
        m[0] = w * (2.0 * std::f64::consts::PI).sqrt() / a * normal_mass(z_lo, z_hi);
        let w2 = w * w;
        let mut h_pow = 1.0; // h^n
        for n in 0..4 {
            let sign = if n % 2 == 0 { 1.0 } else { -1.0 };
            let boundary = w2 / a * (sign * h_pow * l_lo - h_pow * l_hi);
            let previous = if n > 0 { n as f64 * w2 * m[n - 1] } else { 0.0 };
            m[n + 1] = -o * m[n] + boundary + previous;
            h_pow *= h;
        }
    } else {
        // Broad: Gauss–Legendre, 5 points where the lobe changes by at most an e-fold
        // across the window, else 10 (at most 5.6 e-folds at w ≥ 4a, o ≤ 90°); both err
        // below 1e-9.
        let (nodes, weights): (&[f64], &[f64]) = if o.abs() * a <= w * w {
            (&GL5_NODES, &GL5_WEIGHTS)
        } else {
            (&GL10_NODES, &GL10_WEIGHTS)
        };
        for (x, wt) in nodes.iter().zip(weights) {
            let mut add = |s: f64, wt: f64| {
                let l = exp_neg_half_square((o + s) / w);
                let mut sk = 0.5 * wt * l;
                for mk in m.iter_mut() {
                    *mk += sk;
                    sk *= s;
                }
            };
            if *x == 0.0 {
                add(0.0, *wt);
            } else {
                add(h * x, *wt);
                add(-h * x, *wt);
            }
        }
    }
    // ∂L/∂σ = L·2y²/w³ with y = o + s: ∂M_k/∂σ = (2/w³)(o²M_k + 2o·M_{k+1} + M_{k+2}).
    let c = 2.0 / (w * w * w);
    let dm = std::array::from_fn(|k| c * (o * o * m[k] + 2.0 * o * m[k + 1] + m[k + 2]));
    WindowMoments {
        m: [m[0], m[1], m[2]],
        dm_dsigma: dm,
    }
}

/// The window's weights on the slowly varying factor u = F·G/(cos·cos) at the window's
/// low edge, centre and high edge: the parabola through those three values integrated
/// against the lobe gives Σ_e weight\[e\]·u_e. With u ≈ u0 + u1 s + u2 s²/2,
/// u1 = (u+ − u−)/a and u2 = 4(u+ − 2u0 + u−)/a², the weights are
/// (−M1/a + 2M2/a², M0 − 4M2/a², M1/a + 2M2/a²); they sum to M0. Returns the weights and
/// their derivatives in σ.
pub(crate) fn window_weights(
    offset_deg: f64,
    sigma_deg: f64,
    acceptance_deg: f64,
) -> ([f64; 3], [f64; 3]) {
    let WindowMoments { m, dm_dsigma: d } = window_moments(offset_deg, sigma_deg, acceptance_deg);
    let (ia, ia2) = (
        1.0 / acceptance_deg,
        1.0 / (acceptance_deg * acceptance_deg),
    );
    let weights = |m: &[f64; 3]| {
        [
            -m[1] * ia + 2.0 * m[2] * ia2,
            m[0] - 4.0 * m[2] * ia2,
            m[1] * ia + 2.0 * m[2] * ia2,
        ]
    };
    (weights(&m), weights(&d))
}

/// Which term of G/(cos θi cos θr) = min(1/(ci·cr), 2ca/(cψ·ci), 2ca/(cψ·cr)) is the
/// smallest at (θi, θr): no masking, masking of the reflected ray, shadowing of the
/// incident one. G has a kink where it switches.
pub(crate) fn attenuation_branch(theta_i_deg: f64, theta_r_deg: f64) -> u8 {
    PlaneGeometry::new(theta_i_deg, theta_r_deg).attenuation_branch
}

/// The pieces of the window [θr − a/2, θr + a/2] between the kinks of G (where its min
/// switches branch, [`attenuation_branch`]), on each of which u = F·G/(cos·cos) is smooth
/// and the parabola of [`window_weights`] holds: (θr at the piece's middle, its width), in
/// order. Kinks are found between the window's ends and centre and placed by bisection to
/// 1e-12 of the window;
/// they depend on the geometry only, never on the parameters, so splitting there does not
/// make the model jump. One piece, the whole window, almost everywhere (near specular G = 1).
pub fn window_pieces(theta_i_deg: f64, theta_r_deg: f64, acceptance_deg: f64) -> Vec<(f64, f64)> {
    window_nodes(theta_i_deg, theta_r_deg, acceptance_deg)
        .into_iter()
        .map(|(mid, width, _)| (mid, width))
        .collect()
}

/// [`window_pieces`] with each piece's geometry at its low end, middle and high end.
pub(crate) fn window_nodes(
    theta_i_deg: f64,
    theta_r_deg: f64,
    acceptance_deg: f64,
) -> Vec<(f64, f64, [PlaneGeometry; 3])> {
    let (lo, a) = (theta_r_deg - 0.5 * acceptance_deg, acceptance_deg);
    let hi = lo + a;
    let ends = [lo, theta_r_deg, hi];
    let nodes = ends.map(|t| PlaneGeometry::new(theta_i_deg, t));
    if nodes[0].attenuation_branch == nodes[1].attenuation_branch
        && nodes[1].attenuation_branch == nodes[2].attenuation_branch
    {
        return vec![(theta_r_deg, a, nodes)];
    }
    let mut cuts = vec![lo];
    // A branch switch between two samples half a window apart is placed by bisection; two
    // switches within half a degree (out of a branch and back) do not occur in G.
    for k in 0..2 {
        let branch = nodes[k].attenuation_branch;
        if branch == nodes[k + 1].attenuation_branch {
            continue;
        }
        let (mut left, mut right) = (ends[k], ends[k + 1]);
        while right - left > 1e-12 * a {
            let mid = 0.5 * (left + right);
            if attenuation_branch(theta_i_deg, mid) == branch {
                left = mid;
            } else {
                right = mid;
            }
        }
        let cut = 0.5 * (left + right);
        if cut - cuts[cuts.len() - 1] > 1e-9 * a && hi - cut > 1e-9 * a {
            cuts.push(cut);
        }
    }
    cuts.push(hi);
    cuts.windows(2)
        .map(|w| {
            let (mid, width) = (0.5 * (w[0] + w[1]), w[1] - w[0]);
            (
                mid,
                width,
                [w[0], mid, w[1]].map(|t| PlaneGeometry::new(theta_i_deg, t)),
            )
        })
        .collect()
}

/// Radiance factor and its gradient [∂/∂σ (per degree), ∂/∂ρs, ∂/∂ρd, ∂/∂η] at a
/// precomputed geometry; `acceptance_deg` = `Some(a)` with a > 0 averages the whole model
/// over the detector's window (see the module's documentation): per piece of the window
/// between G's kinks ([`window_pieces`]), the piece's share of the window times the
/// parabola rule of [`window_weights`] on that piece.
#[inline]
pub fn evaluate(p: &Params, g: &PlaneGeometry, acceptance_deg: Option<f64>) -> (f64, [f64; 4]) {
    match acceptance_deg {
        Some(a) if a > 0.0 => {
            let (mut shape, mut d_sigma, mut d_eta) = (0.0, 0.0, 0.0);
            for (mid, width, nodes) in window_nodes(g.theta_i_deg, g.theta_r_deg, a) {
                let (weights, d_weights) = window_weights(mid - g.theta_i_deg, p.sigma_deg, width);
                let share = width / a;
                for (k, node) in nodes.iter().enumerate() {
                    let (f, df) = fresnel_with_derivative(node.sin2_psi, node.cos_psi, p.eta);
                    let hh = node.attenuation_over_cosines * share;
                    shape += weights[k] * f * hh;
                    d_sigma += d_weights[k] * f * hh;
                    d_eta += weights[k] * df * hh;
                }
            }
            (
                p.rho_s * shape + p.rho_d,
                [p.rho_s * d_sigma, shape, 1.0, p.rho_s * d_eta],
            )
        }
        _ => {
            let (e, de) = lobe_with_derivative(g.offset_deg, p.sigma_deg);
            let (f, df) = fresnel_with_derivative(g.sin2_psi, g.cos_psi, p.eta);
            let h = g.attenuation_over_cosines;
            let specular = f * h * e;
            (
                p.rho_s * specular + p.rho_d,
                [p.rho_s * f * h * de, specular, 1.0, p.rho_s * df * h * e],
            )
        }
    }
}

/// The detector's positions, as (offset from the reading's centre in θr, degrees;
/// weight), over a reading taken while its arm moved `span_deg` at a constant speed (a
/// sweep's bin): the reading is the mean over its travel of what a still detector of
/// window `window_deg` sees, and the weights sum to 1. A still reading (span 0) is its
/// centre alone. Otherwise the travel is cut into segments of at most half the window and
/// each gets 3-point Gauss–Legendre: the still detector's reading, a lobe convolved with
/// the window, is smooth on the scale of the window, so that is within 3e-7 of the
/// travel's mean for σ ≥ 0.5° (host/tests/it/model.rs checks it against dense quadrature;
/// segments of a whole window would err by 5e-6).
/// The nodes depend on the geometry alone, never on the parameters, so the model does not
/// jump as σ changes.
pub(crate) fn travel_nodes(span_deg: f64, window_deg: f64) -> Vec<(f64, f64)> {
    let span = span_deg.abs();
    if span == 0.0 || !span.is_finite() || !(window_deg > 0.0) {
        return vec![(0.0, 1.0)];
    }
    const X: f64 = 0.774_596_669_241_483_4; // √(3/5)
    const W: [f64; 3] = [5.0 / 18.0, 8.0 / 18.0, 5.0 / 18.0];
    let segments = (span / (0.5 * window_deg)).ceil().max(1.0) as usize;
    let width = span / segments as f64;
    let mut out = Vec::with_capacity(3 * segments);
    for j in 0..segments {
        let centre = -0.5 * span + (j as f64 + 0.5) * width;
        for (k, x) in [-X, 0.0, X].iter().enumerate() {
            out.push((centre + 0.5 * width * x, W[k] / segments as f64));
        }
    }
    out
}

/// The widest uniform window the parabola rule of [`window_weights`] is given when a
/// point detector's travel is the window, degrees: wider, u = F·G/(cos·cos) is no longer
/// a parabola across it to 1e-6.
const MAX_TRAVEL_WINDOW_DEG: f64 = 0.5;

/// Most steps a [`DetectorResponse`] has: enough for a measured response at a step of a
/// fifth of its FWHM out to its tails (a Gaussian to ±2.5 FWHM), few enough that a sweep's
/// 1,400 bins stay a fit of seconds.
pub const MAX_RESPONSE_STEPS: usize = 15;

/// The detector's angular response in θr as the fit uses it: a histogram of equal steps,
/// each a uniform window of width `step_deg` at its offset from the reading's θr with its
/// share of the response (the shares sum to 1). A top-hat acceptance is one step; a
/// measured response ([`crate::instrument::profile`]) is the mean of the instrument's
/// response over each step, which keeps its variance (Sheppard: the histogram's spread
/// within steps makes up what the steps' centres lose). Copy, so that options holding it
/// stay plain values.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DetectorResponse {
    step_deg: f64,
    len: usize,
    steps: [(f64, f64); MAX_RESPONSE_STEPS],
}

/// A response that cannot be used.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ResponseError {
    /// The step is not a positive finite width.
    #[error("the response's step must be a positive width in degrees, not {0}")]
    Step(f64),
    /// Too many or no steps.
    #[error("a response has 1 to {MAX_RESPONSE_STEPS} steps, not {0}")]
    Steps(usize),
    /// A share is negative or not finite, or they do not add up to a positive total.
    #[error("the response's shares must be finite, ≥ 0 and add up to more than 0")]
    Shares,
    /// An offset is not finite or beyond ±10°.
    #[error("a response step's offset must be finite and within ±10°, not {0}")]
    Offset(f64),
}

impl DetectorResponse {
    /// A uniform window of full width `width_deg` (> 0) centred on the reading.
    pub fn top_hat(width_deg: f64) -> DetectorResponse {
        let mut steps = [(0.0, 0.0); MAX_RESPONSE_STEPS];
        steps[0] = (0.0, 1.0);
        DetectorResponse {
            step_deg: width_deg,
            len: 1,
            steps,
        }
    }

    /// A histogram of `shares` (normalized here) on steps of `step_deg`, step k centred at
    /// `first_offset_deg + k·step_deg` from the reading's θr.
    pub fn from_steps(
        step_deg: f64,
        first_offset_deg: f64,
        shares: &[f64],
    ) -> Result<DetectorResponse, ResponseError> {
        if !(step_deg > 0.0 && step_deg.is_finite() && step_deg <= 10.0) {
            return Err(ResponseError::Step(step_deg));
        }
        if shares.is_empty() || shares.len() > MAX_RESPONSE_STEPS {
            return Err(ResponseError::Steps(shares.len()));
        }
        let total: f64 = shares.iter().sum();
        if shares.iter().any(|s| !(s.is_finite() && *s >= 0.0))
            || !(total > 0.0 && total.is_finite())
        {
            return Err(ResponseError::Shares);
        }
        let mut steps = [(0.0, 0.0); MAX_RESPONSE_STEPS];
        for (k, share) in shares.iter().enumerate() {
            let offset = first_offset_deg + k as f64 * step_deg;
            if !(offset.is_finite() && offset.abs() <= 10.0) {
                return Err(ResponseError::Offset(offset));
            }
            steps[k] = (offset, share / total);
        }
        Ok(DetectorResponse {
            step_deg,
            len: shares.len(),
            steps,
        })
    }

    /// Width of each step, degrees.
    pub fn step_deg(&self) -> f64 {
        self.step_deg
    }

    /// The steps: (offset from the reading's θr, degrees; share).
    pub fn steps(&self) -> &[(f64, f64)] {
        &self.steps[..self.len]
    }

    /// Mean offset, degrees (0 for a centred response).
    pub fn mean_deg(&self) -> f64 {
        self.steps().iter().map(|(o, w)| o * w).sum()
    }

    /// Variance of the response, degrees²: the steps' spread plus each step's own (a²/12).
    pub fn variance_deg2(&self) -> f64 {
        let mean = self.mean_deg();
        self.steps()
            .iter()
            .map(|(o, w)| w * (o - mean).powi(2))
            .sum::<f64>()
            + self.step_deg * self.step_deg / 12.0
    }

    /// The width of the top-hat of the same variance, degrees (√(12·variance)): what a
    /// display or a seeding grid can use in place of the whole shape.
    pub fn equivalent_width_deg(&self) -> f64 {
        (12.0 * self.variance_deg2()).sqrt()
    }

    /// The width one number stands for: a top-hat's own (to the bit), else
    /// [`DetectorResponse::equivalent_width_deg`].
    pub fn width_deg(&self) -> f64 {
        if self.is_top_hat() {
            self.step_deg
        } else {
            self.equivalent_width_deg()
        }
    }

    /// Whether this is a single uniform window (the declared top-hat).
    pub fn is_top_hat(&self) -> bool {
        self.len == 1
    }
}

/// The window a reading is averaged over, degrees, and the detector's positions across
/// its travel ([`travel_nodes`]) combined with the response's steps: with a response, its
/// step width and, for each travel node and step, (offset, weight) (a top-hat's one step
/// at offset 0 and share 1 leaves the travel's nodes as they are, to the last bit); without
/// one, a detector that moved `span` sees a uniform window of the span itself, taken as n
/// adjacent windows of span/n ≤ 0.5° (exactly the same mean); a still point detector, no
/// window.
pub(crate) fn reading_window(
    span_deg: f64,
    response: Option<&DetectorResponse>,
) -> (Option<f64>, Vec<(f64, f64)>) {
    let span = span_deg.abs();
    match response.filter(|r| r.step_deg > 0.0) {
        Some(r) if r.is_top_hat() => (Some(r.step_deg), travel_nodes(span, r.step_deg)),
        Some(r) => {
            let travel = travel_nodes(span, r.step_deg);
            let nodes = travel
                .iter()
                .flat_map(|&(along, weight)| {
                    r.steps()
                        .iter()
                        .filter(|(_, share)| *share > 0.0)
                        .map(move |&(offset, share)| (along + offset, weight * share))
                })
                .collect();
            (Some(r.step_deg), nodes)
        }
        None if span > 0.0 && span.is_finite() => {
            let n = (span / MAX_TRAVEL_WINDOW_DEG).ceil().max(1.0) as usize;
            let width = span / n as f64;
            (
                Some(width),
                (0..n)
                    .map(|j| (-0.5 * span + (j as f64 + 0.5) * width, 1.0 / n as f64))
                    .collect(),
            )
        }
        None => (None, vec![(0.0, 1.0)]),
    }
}

/// The declared acceptance as a response: `Some(a)` with a > 0 a top-hat, else none.
pub fn top_hat_response(acceptance_deg: Option<f64>) -> Option<DetectorResponse> {
    acceptance_deg
        .filter(|&a| a > 0.0)
        .map(DetectorResponse::top_hat)
}

/// Radiance factor and gradient of a reading centred at (θi, θr) whose detector moved
/// `span_deg` in θr while it integrated (0: a still reading), seen through the acceptance
/// `acceptance_deg`: the mean over the travel ([`reading_window`]) of [`evaluate`].
pub fn evaluate_reading(
    p: &Params,
    theta_i_deg: f64,
    theta_r_deg: f64,
    span_deg: f64,
    acceptance_deg: Option<f64>,
) -> (f64, [f64; 4]) {
    evaluate_reading_through(
        p,
        theta_i_deg,
        theta_r_deg,
        span_deg,
        top_hat_response(acceptance_deg).as_ref(),
    )
}

/// [`evaluate_reading`] through a detector response of any shape (`None`: a point
/// detector).
pub fn evaluate_reading_through(
    p: &Params,
    theta_i_deg: f64,
    theta_r_deg: f64,
    span_deg: f64,
    response: Option<&DetectorResponse>,
) -> (f64, [f64; 4]) {
    let (window, nodes) = reading_window(span_deg, response);
    let (mut value, mut gradient) = (0.0, [0.0; 4]);
    for (offset, weight) in nodes {
        let (v, g) = evaluate(
            p,
            &PlaneGeometry::new(theta_i_deg, theta_r_deg + offset),
            window,
        );
        value += weight * v;
        for (total, gi) in gradient.iter_mut().zip(g) {
            *total += weight * gi;
        }
    }
    (value, gradient)
}

/// Radiance factor of the TSL model at (θi, θr), degrees.
pub fn radiance_factor(p: &Params, theta_i_deg: f64, theta_r_deg: f64) -> f64 {
    evaluate(p, &PlaneGeometry::new(theta_i_deg, theta_r_deg), None).0
}

/// Radiance factor and its analytic gradient [∂/∂σ, ∂/∂ρs, ∂/∂ρd, ∂/∂η].
pub fn radiance_factor_with_gradient(
    p: &Params,
    theta_i_deg: f64,
    theta_r_deg: f64,
) -> (f64, [f64; 4]) {
    evaluate(p, &PlaneGeometry::new(theta_i_deg, theta_r_deg), None)
}

/// Radiance factor seen by a detector of full acceptance `acceptance_deg` (uniform in θr):
/// the whole model averaged over the window, at every σ (0 or less: the point model).
pub fn observed_radiance_factor(
    p: &Params,
    theta_i_deg: f64,
    theta_r_deg: f64,
    acceptance_deg: f64,
) -> f64 {
    evaluate(
        p,
        &PlaneGeometry::new(theta_i_deg, theta_r_deg),
        Some(acceptance_deg),
    )
    .0
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
                assert!(
                    (ours - textbook).abs() <= 1e-12 * textbook,
                    "ψ {psi} η {eta}: {ours} vs {textbook}"
                );
            }
        }
    }

    /// (1/a)∫ s^k L(o + s) ds by composite Simpson on 20,000 panels (relative error below
    /// 1e-7 even where the narrowest lobe's tail falls steeply across the window).
    fn dense_moments(offset: f64, sigma: f64, a: f64) -> [f64; 3] {
        let n = 20_000;
        let h = a / n as f64;
        let mut m = [0.0; 3];
        for j in 0..=n {
            let s = -0.5 * a + h * j as f64;
            let weight = if j == 0 || j == n {
                1.0
            } else if j % 2 == 1 {
                4.0
            } else {
                2.0
            };
            let l = (-(offset + s).powi(2) / (8.0 * sigma * sigma)).exp();
            for (k, mk) in m.iter_mut().enumerate() {
                *mk += weight * s.powi(k as i32) * l * h / (3.0 * a);
            }
        }
        m
    }

    #[test]
    fn window_moments_match_dense_quadrature_and_their_sigma_derivative() {
        for a in [0.5, 1.0, 2.0] {
            for sigma in [
                0.01, 0.1, 0.3, 0.5, 0.8, 1.9, 1.99, 2.01, 3.9, 4.1, 20.0, 90.0,
            ] {
                for offset in [
                    0.0, 0.2, -0.45, 0.5, 1.0, -2.5, 6.0, 15.0, 17.0, 40.0, -70.0, 89.0,
                ] {
                    let got = window_moments(offset, sigma, a);
                    let want = dense_moments(offset, sigma, a);
                    // Scale of each moment: (a/2)^k times the lobe's size in the window.
                    let size = want[0].abs().max(1e-300);
                    for k in 0..3 {
                        let scale = size * (0.5 * a).powi(k as i32);
                        assert!(
                            (got.m[k] - want[k]).abs() <= 1e-6 * scale + 1e-280,
                            "a {a} σ {sigma} o {offset} M{k}: {} vs {}",
                            got.m[k],
                            want[k]
                        );
                        let hstep = 1e-6 * sigma;
                        let fd = (window_moments(offset, sigma + hstep, a).m[k]
                            - window_moments(offset, sigma - hstep, a).m[k])
                            / (2.0 * hstep);
                        let d = got.dm_dsigma[k];
                        assert!(
                            (d - fd).abs() <= 1e-5 * (fd.abs() + scale / sigma) + 1e-280,
                            "a {a} σ {sigma} o {offset} dM{k}: {d} vs {fd}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn windowed_lobe_tends_to_point_lobe_for_tiny_window() {
        for offset in [0.0, 0.7, 2.0] {
            let (e, de) = lobe_with_derivative(offset, 0.8);
            let (m, dm) = windowed_lobe_with_derivative(offset, 0.8, 1e-4);
            assert!(
                (e - m).abs() < 1e-8 && (de - dm).abs() < 1e-6,
                "{offset}: {e} {m} {de} {dm}"
            );
        }
    }
}
