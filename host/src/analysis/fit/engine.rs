//! The fit's numerical engine: the data prepared once (distinct geometry terms, the
//! detector window's edge terms, the whitened shared errors), the generalised
//! least-squares cost with its normal equations, the closed-form inner problem in (ρs, ρd),
//! the seeding grid and Levenberg–Marquardt.
//!
//! **Generalised least squares.** The readings' covariance is Σ = D + S Sᵀ, D = diag(std²)
//! and S the shared errors' sensitivities (n × m, m ≪ n). The cost is rᵀ Σ⁻¹ r, by Woodbury:
//! with whitened r̃ = D^(−½) r, S̃ = D^(−½) S and M = I + S̃ᵀS̃ (m × m, Cholesky L once per
//! fit), rᵀ Σ⁻¹ r = r̃ᵀr̃ − |L⁻¹ S̃ᵀ r̃|², and likewise JᵀΣ⁻¹J and JᵀΣ⁻¹r. This equals fitting
//! the shared errors as nuisance parameters with unit Gaussian priors and profiling them
//! out, but keeps Levenberg–Marquardt at four parameters and costs O(n·m) per pass; the
//! parameters' covariance then splits exactly into each shared term's share (fit.rs).
use super::{
    ETA_MAX, ETA_MIN, LinearSolution, Observation, SIGMA_MAX_DEG, SIGMA_MIN_DEG, SharedError,
    Status,
};
use crate::analysis::linalg::{self, Square};
use crate::analysis::model::{self, DetectorResponse, Params, PlaneGeometry};

/// The detector window a problem is built with: the declared acceptance (`Option<f64>`, a
/// top-hat of that full width) or a response of any shape (`Option<DetectorResponse>`).
pub(crate) struct Aperture(pub Option<DetectorResponse>);

impl From<Option<f64>> for Aperture {
    fn from(acceptance_deg: Option<f64>) -> Aperture {
        Aperture(model::top_hat_response(acceptance_deg))
    }
}

impl From<Option<DetectorResponse>> for Aperture {
    fn from(response: Option<DetectorResponse>) -> Aperture {
        Aperture(response.filter(|r| r.step_deg() > 0.0))
    }
}

/// One reading prepared for the fit.
#[derive(Clone, Copy, Debug)]
pub(super) struct Point {
    /// Geometry at the window's centre (θr shifted by the arm offset in use).
    pub geometry: PlaneGeometry,
    /// The detector's travel while the reading integrated, degrees (0: a still reading).
    pub(crate) span_deg: f64,
    pub y: f64,
    /// sqrt of the weight 1/std² (1 without uncertainties).
    pub(crate) sqrt_w: f64,
    /// Index of the lobe offset (θr − θi with a window, |θr − θi| without) in
    /// [`LeastSquaresProblem::offsets`]: the seeding grid's lobe and the window's edges.
    offset: u32,
    /// This reading's pieces in [`LeastSquaresProblem::pieces`].
    pieces: (u32, u32),
    /// Index of (sin² ψ, cos ψ) at the window's centre in [`LeastSquaresProblem::centre_psis`].
    centre_psi: u32,
}

/// A piece of a reading's window on which G/(cos·cos) is smooth (the whole window almost
/// always; the point itself without a window).
#[derive(Clone, Copy, Debug)]
struct Piece {
    /// Index of (offset of the piece's middle, width) in [`LeastSquaresProblem::lobe_keys`].
    lobe: u32,
    /// Index of (sin² ψ, cos ψ) at the piece's low end, middle and high end in
    /// [`LeastSquaresProblem::psis`] (all the middle's without a window).
    psi: [u32; 3],
    /// G/(cos θi cos θr) there (ends 0 without a window).
    h: [f64; 3],
    /// Its share of the reading beyond its share of the acceptance window (which the lobe
    /// table holds): its place's weight along the detector's travel, and without an
    /// acceptance its width over the travel window's (1 for every piece of a still reading).
    share: f64,
}

/// The shared errors, whitened, with the Cholesky factor of M = I + S̃ᵀS̃.
pub(super) struct Shared {
    /// Number of shared terms.
    pub m: usize,
    /// S̃, row-major n × m: s_ik / std_i.
    pub s: Vec<f64>,
    /// Lower Cholesky factor of M.
    pub l: Square,
}

impl Shared {
    fn new(observations: &[Observation], shared: &[SharedError]) -> Shared {
        let m = shared.len();
        let n = observations.len();
        let mut s = vec![0.0; n * m];
        for (k, term) in shared.iter().enumerate() {
            for (i, o) in observations.iter().enumerate() {
                s[i * m + k] = term.sensitivity[i] / o.std.unwrap_or(1.0);
            }
        }
        let mut mm = Square::identity(m);
        for i in 0..n {
            let row = &s[i * m..(i + 1) * m];
            for a in 0..m {
                for b in 0..=a {
                    *mm.at_mut(a, b) += row[a] * row[b];
                }
            }
        }
        for a in 0..m {
            for b in 0..a {
                *mm.at_mut(b, a) = mm.at(a, b);
            }
        }
        // I + S̃ᵀS̃ ≥ I is positive definite; a failure means non-finite input, which
        // validation refuses, so the identity is only a safe stand-in.
        let l = linalg::cholesky(&mm).unwrap_or_else(|| Square::identity(m));
        Shared { m, s, l }
    }

    /// Whitened sensitivities of reading `i`.
    #[inline]
    pub fn row(&self, i: usize) -> &[f64] {
        &self.s[i * self.m..(i + 1) * self.m]
    }
}

/// The fit's data with the distinct values of its geometry terms: a measurement grid
/// repeats lobe offsets and ψ many times (284 geometries have 61 distinct |θr − θi| and
/// 111 distinct ψ), so the lobe's window terms and the Fresnel terms are evaluated once
/// per distinct value and per pass.
pub(super) struct LeastSquaresProblem {
    pub points: Vec<Point>,
    /// Width of the response's steps, degrees (the acceptance itself for a top-hat).
    pub acceptance_deg: Option<f64>,
    /// The detector's response (`None`: a point detector).
    pub response: Option<DetectorResponse>,
    pub weighted: bool,
    pub shared: Shared,
    /// Arm zero offset applied to every θr, degrees.
    pub(crate) shift_deg: f64,
    /// Every reading's pieces.
    pieces: Vec<Piece>,
    /// Distinct lobe offsets of the readings (signed with a window, else |θr − θi|).
    offsets: Vec<f64>,
    /// Distinct (offset of a piece's middle, piece width) (width 0 without a window).
    lobe_keys: Vec<(f64, f64)>,
    /// Distinct (sin² ψ, cos ψ) of the pieces' nodes.
    psis: Vec<(f64, f64)>,
    /// Distinct (sin² ψ, cos ψ) at the readings' window centres (the seeding grid's).
    centre_psis: Vec<(f64, f64)>,
    /// Per-pass tables, reused across passes.
    scratch: std::cell::RefCell<Scratch>,
}

/// A lobe table entry: the window's weights on u at (low edge, centre, high edge) and
/// their σ-derivatives ([0, L, 0] and [0, ∂L/∂σ, 0] without a window).
type LobeEntry = ([f64; 3], [f64; 3]);

#[derive(Default)]
struct Scratch {
    lobe: Vec<LobeEntry>,
    fresnel: Vec<(f64, f64)>,
    q: Vec<f64>,
    p: Vec<[f64; 4]>,
}

/// Distinct values of `keys` (by bits) and each key's index among them.
fn distinct<K: Copy + PartialEq, F: Fn(K) -> u128>(keys: &[K], bits: F) -> (Vec<K>, Vec<u32>) {
    let mut order: Vec<u32> = (0..keys.len() as u32).collect();
    order.sort_unstable_by_key(|&k| bits(keys[k as usize]));
    let mut values: Vec<K> = Vec::new();
    let mut index = vec![0u32; keys.len()];
    let mut last: Option<u128> = None;
    for k in order {
        let b = bits(keys[k as usize]);
        if last != Some(b) {
            values.push(keys[k as usize]);
            last = Some(b);
        }
        index[k as usize] = (values.len() - 1) as u32;
    }
    (values, index)
}

/// A piece of a reading's window before the distinct values are taken: (lobe offset: of the
/// piece's middle with a window, |θr − θi| without; the piece's width, 0 without a window;
/// its three nodes; its share of the reading).
type RawPiece = (f64, f64, [PlaneGeometry; 3], f64);

/// Per reading its pieces ([`RawPiece`]), and each reading's range of them. A reading
/// taken while the detector moved (a sweep's bin) is the mean of the windows along its
/// travel (model::reading_window).
fn raw_pieces(
    observations: &[Observation],
    centres: &[PlaneGeometry],
    response: Option<&DetectorResponse>,
) -> (Vec<RawPiece>, Vec<(u32, u32)>) {
    let acceptance_deg = response.map(DetectorResponse::step_deg);
    let mut raw_pieces: Vec<RawPiece> = Vec::with_capacity(centres.len());
    let mut ranges = Vec::with_capacity(centres.len());
    for (o, g) in observations.iter().zip(centres) {
        let start = raw_pieces.len() as u32;
        let (window, travel) = model::reading_window(o.theta_r_span_deg, response);
        for (along, weight) in travel {
            let theta_r = g.theta_r_deg + along;
            match window {
                Some(a) => {
                    for (mid, width, nodes) in model::window_nodes(g.theta_i_deg, theta_r, a) {
                        // The share of the acceptance window is in the lobe table; of a
                        // travel window (no acceptance), here.
                        let share = if acceptance_deg.is_some() {
                            weight
                        } else {
                            weight * width / a
                        };
                        raw_pieces.push((mid - g.theta_i_deg, width, nodes, share));
                    }
                }
                None => {
                    let point = if along == 0.0 {
                        *g
                    } else {
                        PlaneGeometry::new(g.theta_i_deg, theta_r)
                    };
                    raw_pieces.push((point.offset_deg.abs(), 0.0, [point; 3], weight));
                }
            }
        }
        ranges.push((start, raw_pieces.len() as u32));
    }
    (raw_pieces, ranges)
}

impl LeastSquaresProblem {
    /// The problem of `observations` (validated) with their shared errors, the detector
    /// window `acceptance_deg` (`None` or ≤ 0: a point detector) and every θr shifted by
    /// `shift_deg` (the arm zero offset).
    pub fn new(
        observations: &[Observation],
        shared: &[SharedError],
        aperture: impl Into<Aperture>,
        shift_deg: f64,
    ) -> LeastSquaresProblem {
        let weighted = observations.first().is_some_and(|o| o.std.is_some());
        let response = aperture.into().0;
        let acceptance_deg = response.map(|r| r.step_deg());
        let centres: Vec<PlaneGeometry> = observations
            .iter()
            .map(|o| PlaneGeometry::new(o.theta_i_deg, o.theta_r_deg + shift_deg))
            .collect();
        let (raw_pieces, ranges) = raw_pieces(observations, &centres, response.as_ref());
        let offsets_raw: Vec<f64> = centres
            .iter()
            .map(|g| {
                if acceptance_deg.is_some() {
                    g.offset_deg
                } else {
                    g.offset_deg.abs()
                }
            })
            .collect();
        let keys: Vec<(f64, f64)> = raw_pieces.iter().map(|p| (p.0, p.1)).collect();
        // A piece without a window is its middle node only.
        let psi_keys: Vec<(f64, f64)> = raw_pieces
            .iter()
            .flat_map(|p| p.2.iter().map(|g| (g.sin2_psi, g.cos_psi)))
            .collect();
        let pair = |(a, b): (f64, f64)| ((a.to_bits() as u128) << 64) | b.to_bits() as u128;
        let (offsets, offset_index) = distinct(&offsets_raw, |v| v.to_bits() as u128);
        let (lobe_keys, lobe_index) = distinct(&keys, pair);
        let (psis, psi_index) = distinct(&psi_keys, pair);
        let centre_keys: Vec<(f64, f64)> =
            centres.iter().map(|g| (g.sin2_psi, g.cos_psi)).collect();
        let (centre_psis, centre_index) = distinct(&centre_keys, pair);
        let pieces = raw_pieces
            .iter()
            .enumerate()
            .map(|(k, (_, width, nodes, share))| {
                let windowed = *width > 0.0;
                Piece {
                    lobe: lobe_index[k],
                    psi: if windowed {
                        [psi_index[3 * k], psi_index[3 * k + 1], psi_index[3 * k + 2]]
                    } else {
                        [psi_index[3 * k + 1]; 3]
                    },
                    h: if windowed {
                        std::array::from_fn(|e| nodes[e].attenuation_over_cosines)
                    } else {
                        [0.0, nodes[1].attenuation_over_cosines, 0.0]
                    },
                    share: *share,
                }
            })
            .collect();
        let points = observations
            .iter()
            .zip(&centres)
            .enumerate()
            .map(|(k, (o, geometry))| Point {
                geometry: *geometry,
                span_deg: o.theta_r_span_deg,
                y: o.radiance_factor,
                sqrt_w: o.std.map_or(1.0, |s| 1.0 / s),
                offset: offset_index[k],
                pieces: ranges[k],
                centre_psi: centre_index[k],
            })
            .collect();
        LeastSquaresProblem {
            points,
            acceptance_deg,
            response,
            weighted,
            shared: Shared::new(observations, shared),
            shift_deg,
            pieces,
            offsets,
            lobe_keys,
            psis,
            centre_psis,
            scratch: Default::default(),
        }
    }

    /// Fill `out` with the lobe's window weights on each distinct piece, scaled by the
    /// piece's share of the acceptance window (a piece of width 0: the point lobe), at σ;
    /// a reading taken while moving scales them further by its pieces' shares of its travel.
    fn lobe_table(&self, sigma_deg: f64, out: &mut Vec<LobeEntry>) {
        out.clear();
        out.extend(self.lobe_keys.iter().map(|&(o, width)| {
            if width > 0.0 {
                let (w, dw) = model::window_weights(o, sigma_deg, width);
                // Without an acceptance the window is a moving detector's travel, whose
                // share is all in the piece's.
                let share = self.acceptance_deg.map_or(1.0, |a| width / a);
                (w.map(|v| v * share), dw.map(|v| v * share))
            } else {
                let (e, de) = model::lobe_with_derivative(o, sigma_deg);
                ([0.0, e, 0.0], [0.0, de, 0.0])
            }
        }));
    }

    /// The lobe alone (window mean M0, or the point lobe) per distinct reading offset: the
    /// seeding grid's cheaper model, with F and G/(cos·cos) at the window's centre. A lobe
    /// four windows wide or more is taken at the centre too (the window changes it by less
    /// than a²/(24·(2σ)²) < 0.2 %): the grid only has to find the basins.
    fn seed_lobe_table(&self, sigma_deg: f64, out: &mut Vec<f64>) {
        out.clear();
        // A response of several steps seeds with the top-hat of its variance: the grid
        // only has to find the basins.
        let seed_window = self.response.map(|r| r.width_deg());
        match seed_window {
            Some(a) if 2.0 * sigma_deg < 4.0 * a => out.extend(
                self.offsets
                    .iter()
                    .map(|&o| model::windowed_lobe_with_derivative(o, sigma_deg, a).0),
            ),
            _ => out.extend(
                self.offsets
                    .iter()
                    .map(|&o| model::lobe_with_derivative(o, sigma_deg).0),
            ),
        }
    }

    /// Model terms of one point from the pass's tables: (shape, ∂shape/∂σ, ∂shape/∂η)
    /// with `fresnel` holding (F, ∂F/∂η) or (F/(η²−1), its ∂η) per ψ.
    #[inline]
    fn terms(&self, pt: &Point, lobe: &[LobeEntry], fresnel: &[(f64, f64)]) -> (f64, f64, f64) {
        let (mut shape, mut d_sigma, mut d_eta) = (0.0, 0.0, 0.0);
        // Without a window only the middle node carries weight.
        let nodes = if self.acceptance_deg.is_some() {
            0..3
        } else {
            1..2
        };
        for piece in &self.pieces[pt.pieces.0 as usize..pt.pieces.1 as usize] {
            let (w, dw) = &lobe[piece.lobe as usize];
            // A still reading's pieces have share 1: its terms are added as they are, so
            // its model is the same to the last bit as before bins were modelled.
            let share = piece.share;
            // A moving point detector's pieces are windows (its travel) even without an
            // acceptance: all three nodes (zero at the ends of a point piece).
            for e in if pt.span_deg > 0.0 {
                0..3
            } else {
                nodes.clone()
            } {
                let (f, df) = fresnel[piece.psi[e] as usize];
                let (wh, dwh) = if share == 1.0 {
                    (w[e] * piece.h[e], dw[e] * piece.h[e])
                } else {
                    (share * w[e] * piece.h[e], share * dw[e] * piece.h[e])
                };
                shape += wh * f;
                d_sigma += dwh * f;
                d_eta += wh * df;
            }
        }
        (shape, d_sigma, d_eta)
    }

    /// Cost rᵀΣ⁻¹r at x = [ln σ, A = ρs·(η²−1), ρd, η], with JᵀΣ⁻¹J and JᵀΣ⁻¹r in x when
    /// `jacobian`.
    pub(crate) fn accumulate(
        &self,
        x: &[f64; 4],
        jacobian: bool,
    ) -> (f64, [[f64; 4]; 4], [f64; 4]) {
        let sigma = x[0].exp();
        let (amplitude, rho_d, eta) = (x[1], x[2], x[3]);
        let mut cost = 0.0;
        let mut a = [[0.0; 4]; 4];
        let mut g = [0.0; 4];
        let mut scratch = self.scratch.borrow_mut();
        let Scratch {
            lobe,
            fresnel,
            q,
            p,
        } = &mut *scratch;
        self.lobe_table(sigma, lobe);
        fresnel.clear();
        fresnel.extend(
            self.psis
                .iter()
                .map(|&(s2, c)| model::reduced_fresnel_with_derivative(s2, c, eta)),
        );
        let m = self.shared.m;
        q.clear();
        q.resize(m, 0.0);
        p.clear();
        p.resize(m, [0.0; 4]);
        for (i, pt) in self.points.iter().enumerate() {
            let (shape, d_sigma, d_eta) = self.terms(pt, lobe, fresnel);
            let f = amplitude * shape + rho_d;
            let r = pt.sqrt_w * (f - pt.y);
            cost += r * r;
            let j = [
                pt.sqrt_w * amplitude * d_sigma * sigma,
                pt.sqrt_w * shape,
                pt.sqrt_w,
                pt.sqrt_w * amplitude * d_eta,
            ];
            if jacobian {
                for row in 0..4 {
                    g[row] += j[row] * r;
                    for col in row..4 {
                        a[row][col] += j[row] * j[col];
                    }
                }
            }
            if m > 0 {
                for (k, &s) in self.shared.row(i).iter().enumerate() {
                    q[k] += s * r;
                    if jacobian {
                        for c in 0..4 {
                            p[k][c] += s * j[c];
                        }
                    }
                }
            }
        }
        if m > 0 {
            // Woodbury: subtract the part the shared errors explain.
            linalg::forward_substitute(&self.shared.l, q);
            cost -= q.iter().map(|v| v * v).sum::<f64>();
            cost = cost.max(0.0);
            if jacobian {
                for c in 0..4 {
                    let mut column: Vec<f64> = p.iter().map(|row| row[c]).collect();
                    linalg::forward_substitute(&self.shared.l, &mut column);
                    for (k, v) in column.into_iter().enumerate() {
                        p[k][c] = v;
                    }
                }
                for row in 0..4 {
                    g[row] -= (0..m).map(|k| p[k][row] * q[k]).sum::<f64>();
                    for col in row..4 {
                        a[row][col] -= (0..m).map(|k| p[k][row] * p[k][col]).sum::<f64>();
                    }
                }
            }
        }
        for row in 0..4 {
            for col in 0..row {
                a[row][col] = a[col][row];
            }
        }
        (cost, a, g)
    }

    /// Per reading, in input order: whitened residual (f − y)/std and whitened gradient in
    /// x = [ln σ, A, ρd, η] (independent noise only; the shared part is applied by the caller).
    pub fn rows(&self, x: &[f64; 4]) -> (Vec<f64>, Vec<[f64; 4]>) {
        let sigma = x[0].exp();
        let (amplitude, rho_d, eta) = (x[1], x[2], x[3]);
        let mut scratch = self.scratch.borrow_mut();
        let Scratch { lobe, fresnel, .. } = &mut *scratch;
        self.lobe_table(sigma, lobe);
        fresnel.clear();
        fresnel.extend(
            self.psis
                .iter()
                .map(|&(s2, c)| model::reduced_fresnel_with_derivative(s2, c, eta)),
        );
        let mut residuals = Vec::with_capacity(self.points.len());
        let mut jac = Vec::with_capacity(self.points.len());
        for pt in &self.points {
            let (shape, d_sigma, d_eta) = self.terms(pt, lobe, fresnel);
            residuals.push(pt.sqrt_w * (amplitude * shape + rho_d - pt.y));
            jac.push([
                pt.sqrt_w * amplitude * d_sigma * sigma,
                pt.sqrt_w * shape,
                pt.sqrt_w,
                pt.sqrt_w * amplitude * d_eta,
            ]);
        }
        (residuals, jac)
    }

    /// Unweighted model values at x, in input order.
    pub fn values(&self, x: &[f64; 4]) -> Vec<f64> {
        let (r, _) = self.rows(x);
        r.iter()
            .zip(&self.points)
            .map(|(r, pt)| r / pt.sqrt_w + pt.y)
            .collect()
    }

    /// Σ⁻¹-weighted sums (Σ1, Σy, Σy², Σg, Σg², Σgy) for the model f = ρs·g + ρd with g
    /// the specular shape per point: diagonal sums corrected by Woodbury.
    fn linear_sums(&self, g: impl Iterator<Item = f64>) -> [f64; 6] {
        let m = self.shared.m;
        let (mut sw, mut sy, mut syy, mut sg, mut sgg, mut sgy) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        let (mut p1, mut pg, mut py) = (vec![0.0; m], vec![0.0; m], vec![0.0; m]);
        for (i, (pt, g)) in self.points.iter().zip(g).enumerate() {
            let w = pt.sqrt_w * pt.sqrt_w;
            sw += w;
            sy += w * pt.y;
            syy += w * pt.y * pt.y;
            sg += w * g;
            sgg += w * g * g;
            sgy += w * g * pt.y;
            if m > 0 {
                for (k, &s) in self.shared.row(i).iter().enumerate() {
                    p1[k] += s * pt.sqrt_w;
                    pg[k] += s * pt.sqrt_w * g;
                    py[k] += s * pt.sqrt_w * pt.y;
                }
            }
        }
        if m > 0 {
            for v in [&mut p1, &mut pg, &mut py] {
                linalg::forward_substitute(&self.shared.l, v);
            }
            let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
            sw -= dot(&p1, &p1);
            sy -= dot(&p1, &py);
            syy -= dot(&py, &py);
            sg -= dot(&p1, &pg);
            sgg -= dot(&pg, &pg);
            sgy -= dot(&pg, &py);
        }
        [sw, sy, syy, sg, sgg, sgy]
    }

    /// Best non-negative (ρs, ρd) at (σ, η).
    pub(crate) fn linear(&self, sigma_deg: f64, eta: f64) -> LinearSolution {
        let shapes: Vec<f64> = {
            let mut scratch = self.scratch.borrow_mut();
            let Scratch { lobe, fresnel, .. } = &mut *scratch;
            self.lobe_table(sigma_deg, lobe);
            fresnel.clear();
            fresnel.extend(
                self.psis
                    .iter()
                    .map(|&(s2, c)| model::fresnel_with_derivative(s2, c, eta)),
            );
            self.points
                .iter()
                .map(|pt| self.terms(pt, lobe, fresnel).0)
                .collect()
        };
        let [sw, sy, syy, sg, sgg, sgy] = self.linear_sums(shapes.into_iter());
        solve_linear(sw, sy, syy, sg, sgg, sgy)
    }

    /// The best constant ρd (Σ⁻¹-weighted mean, at least 0).
    pub(crate) fn lambert(&self) -> f64 {
        let [sw, sy, ..] = self.linear_sums(std::iter::repeat(0.0));
        (sy / sw).max(0.0)
    }
}

/// (η² − 1), the factor between the fit's amplitude A and ρs.
pub(super) fn eta_factor(eta: f64) -> f64 {
    (eta - 1.0) * (eta + 1.0)
}

pub(super) fn params_of(x: &[f64; 4]) -> Params {
    Params {
        sigma_deg: x[0].exp(),
        rho_s: x[1] / eta_factor(x[3]),
        rho_d: x[2],
        eta: x[3],
    }
}

/// x = [ln σ, A, ρd, η] of parameters.
pub(super) fn x_of(p: &Params) -> [f64; 4] {
    [
        p.sigma_deg.ln(),
        p.rho_s * eta_factor(p.eta),
        p.rho_d,
        p.eta,
    ]
}

/// η = 1 itself has F ≡ 0; the fit stops just above it, where ρs = A/(η²−1) is still
/// finite, and reports η at its bound with ρs undetermined.
pub(super) const ETA_FLOOR: f64 = ETA_MIN + 1e-6;

pub(super) fn lower_bounds() -> [f64; 4] {
    [SIGMA_MIN_DEG.ln(), 0.0, 0.0, ETA_FLOOR]
}

pub(super) fn upper_bounds() -> [f64; 4] {
    [SIGMA_MAX_DEG.ln(), f64::INFINITY, f64::INFINITY, ETA_MAX]
}

/// Closed-form non-negative least squares for f = ρs·g + ρd from the weighted sums.
fn solve_linear(sw: f64, sy: f64, syy: f64, sg: f64, sgg: f64, sgy: f64) -> LinearSolution {
    let cost_of = |a: f64, b: f64| {
        (syy - 2.0 * a * sgy - 2.0 * b * sy + a * a * sgg + 2.0 * a * b * sg + b * b * sw).max(0.0)
    };
    let det = sw * sgg - sg * sg;
    if det > 1e-12 * sw * sgg {
        let rho_s = (sw * sgy - sg * sy) / det;
        let rho_d = (sgg * sy - sg * sgy) / det;
        if rho_s >= 0.0 && rho_d >= 0.0 {
            return LinearSolution {
                rho_s,
                rho_d,
                cost: cost_of(rho_s, rho_d),
            };
        }
    }
    // The unconstrained optimum is infeasible (or g has no shape): the best lies on an edge.
    let lambert = LinearSolution {
        rho_s: 0.0,
        rho_d: (sy / sw).max(0.0),
        cost: cost_of(0.0, (sy / sw).max(0.0)),
    };
    if sgg > 0.0 {
        let rho_s = (sgy / sgg).max(0.0);
        let specular_only = LinearSolution {
            rho_s,
            rho_d: 0.0,
            cost: cost_of(rho_s, 0.0),
        };
        if specular_only.cost < lambert.cost {
            return specular_only;
        }
    }
    lambert
}

/// σ grid of the global search: log-spaced, 1.25 apart, from 0.05° (finer than any
/// sampling here resolves) to 90°.
fn sigma_grid() -> impl Iterator<Item = f64> {
    const RATIO: f64 = 1.25;
    let n = ((SIGMA_MAX_DEG / 0.05).ln() / RATIO.ln()).ceil() as i32;
    (0..=n).map(move |k| (0.05 * RATIO.powi(k)).min(SIGMA_MAX_DEG))
}

/// η grid of the global search: denser near 1, where F changes fastest relative to itself.
const ETA_GRID: [f64; 11] = [
    1.005, 1.01, 1.02, 1.04, 1.08, 1.19, 1.35, 1.6, 2.0, 2.5, 3.0,
];

/// Starting points from the grid: the best (η, ρs, ρd) at each σ, then the lowest local
/// minima of that profile in σ, best first. The grid uses the cheaper seeding model (the
/// window's mean of the lobe alone, F and G/(cos·cos) at the centre, independent noise
/// only): it only has to land in the right basins, which Levenberg–Marquardt then polishes
/// on the full model.
fn seeds(problem: &LeastSquaresProblem, max_seeds: usize) -> Vec<[f64; 4]> {
    let sums = SeedSums::new(problem);
    let (profile, eta_costs) = sigma_profile(problem, &sums);
    let minima: Vec<(f64, [f64; 4])> = (0..profile.len())
        .filter(|&i| {
            let c = profile[i].0;
            (i == 0 || c <= profile[i - 1].0) && (i + 1 == profile.len() || c <= profile[i + 1].0)
        })
        .map(|i| profile[i])
        .collect();
    let mut minima: Vec<(f64, [f64; 4])> = minima
        .into_iter()
        .map(|(c, x)| polish_minimum(problem, &profile, &eta_costs, c, x))
        .collect();
    minima.sort_by(|a, b| a.0.total_cmp(&b.0));
    // Basins far worse than the best on the grid do not compete after polishing either.
    let best_cost = minima.first().map_or(0.0, |m| m.0);
    minima.retain(|m| m.0 <= 2.0 * best_cost + 1e-300);
    minima.truncate(max_seeds);
    minima.into_iter().map(|(_, x)| x).collect()
}

/// The seeding grid's weighted sums: Σw, Σwy, Σwy² over the points, and per η of
/// [`ETA_GRID`] and distinct lobe offset o the sums over the points at o of u = w·F·H,
/// u·y and u·F·H, so each (σ, η) costs three dot products over the distinct offsets (61
/// for the 284-geometry grid) and each σ one lobe term per distinct offset.
struct SeedSums {
    sw: f64,
    sy: f64,
    syy: f64,
    /// Distinct lobe offsets.
    m: usize,
    u: Vec<f64>,
    uy: Vec<f64>,
    uu: Vec<f64>,
}

impl SeedSums {
    fn new(problem: &LeastSquaresProblem) -> SeedSums {
        let (mut sw, mut sy, mut syy) = (0.0, 0.0, 0.0);
        for pt in &problem.points {
            let w = pt.sqrt_w * pt.sqrt_w;
            sw += w;
            sy += w * pt.y;
            syy += w * pt.y * pt.y;
        }
        let m = problem.offsets.len();
        let mut fresnel = vec![0.0; problem.centre_psis.len()];
        let mut u = vec![0.0; ETA_GRID.len() * m];
        let mut uy = vec![0.0; ETA_GRID.len() * m];
        let mut uu = vec![0.0; ETA_GRID.len() * m];
        for (e, &eta) in ETA_GRID.iter().enumerate() {
            for (f, &(s2, c)) in fresnel.iter_mut().zip(&problem.centre_psis) {
                *f = model::fresnel_with_derivative(s2, c, eta).0;
            }
            for pt in &problem.points {
                let fh = fresnel[pt.centre_psi as usize] * pt.geometry.attenuation_over_cosines;
                let w = pt.sqrt_w * pt.sqrt_w;
                let k = e * m + pt.offset as usize;
                u[k] += w * fh;
                uy[k] += w * fh * pt.y;
                uu[k] += w * fh * fh;
            }
        }
        SeedSums {
            sw,
            sy,
            syy,
            m,
            u,
            uy,
            uu,
        }
    }
}

/// The profile over [`sigma_grid`]: at each σ the best (cost, x) over [`ETA_GRID`], and
/// every (σ, η)'s cost (row-major, η fastest).
#[allow(clippy::type_complexity)]
fn sigma_profile(
    problem: &LeastSquaresProblem,
    sums: &SeedSums,
) -> (Vec<(f64, [f64; 4])>, Vec<f64>) {
    let SeedSums {
        sw,
        sy,
        syy,
        m,
        ref u,
        ref uy,
        ref uu,
    } = *sums;
    let mut lobe = Vec::with_capacity(m);
    let mut profile: Vec<(f64, [f64; 4])> = Vec::with_capacity(40);
    let mut eta_costs: Vec<f64> = Vec::with_capacity(40 * ETA_GRID.len());
    for sigma in sigma_grid() {
        problem.seed_lobe_table(sigma, &mut lobe);
        let mut best = (f64::INFINITY, [0.0; 4]);
        for (e, &eta) in ETA_GRID.iter().enumerate() {
            let range = e * m..(e + 1) * m;
            let (sg, sgy, sgg) =
                lobe_dots(&lobe[..], &u[range.clone()], &uy[range.clone()], &uu[range]);
            let s = solve_linear(sw, sy, syy, sg, sgg, sgy);
            eta_costs.push(s.cost);
            if s.cost < best.0 {
                best = (
                    s.cost,
                    [sigma.ln(), s.rho_s * eta_factor(eta), s.rho_d, eta],
                );
            }
        }
        profile.push(best);
    }
    (profile, eta_costs)
}

/// Σ u·l, Σ uy·l and Σ uu·l² over the distinct offsets, with four partial sums per dot
/// product: independent chains the compiler can keep in vector registers.
fn lobe_dots(l: &[f64], u: &[f64], uy: &[f64], uu: &[f64]) -> (f64, f64, f64) {
    let m = u.len();
    let (mut sg4, mut sgy4, mut sgg4) = ([0.0; 4], [0.0; 4], [0.0; 4]);
    let whole = m / 4 * 4;
    for c in (0..whole).step_by(4) {
        for j in 0..4 {
            let lj = l[c + j];
            sg4[j] += u[c + j] * lj;
            sgy4[j] += uy[c + j] * lj;
            sgg4[j] += uu[c + j] * lj * lj;
        }
    }
    for k in whole..m {
        sg4[0] += u[k] * l[k];
        sgy4[0] += uy[k] * l[k];
        sgg4[0] += uu[k] * l[k] * l[k];
    }
    let sum4 = |v: [f64; 4]| (v[0] + v[1]) + (v[2] + v[3]);
    (sum4(sg4), sum4(sgy4), sum4(sgg4))
}

/// A local minimum of the profile polished by parabolas through its neighbours, in ln σ
/// along the profile and in η along its row (starting in the right place of the narrow
/// ρs–η valley of nearly-Fresnel-free papers, η → 1, saves most LM iterations), then on
/// the full model: the start Levenberg–Marquardt gets, and the cost the basins are ranked
/// by (the polished point unless the grid point is better).
fn polish_minimum(
    problem: &LeastSquaresProblem,
    profile: &[(f64, [f64; 4])],
    eta_costs: &[f64],
    c: f64,
    x: [f64; 4],
) -> (f64, [f64; 4]) {
    let n_eta = ETA_GRID.len();
    let i = profile.iter().position(|p| p.1 == x).unwrap_or(0);
    let ln_sigma = if i > 0 && i + 1 < profile.len() {
        parabola_min(
            [profile[i - 1].1[0], x[0], profile[i + 1].1[0]],
            [profile[i - 1].0, c, profile[i + 1].0],
        )
        .unwrap_or(x[0])
    } else {
        x[0]
    };
    let row = &eta_costs[i * n_eta..(i + 1) * n_eta];
    let e = ETA_GRID.iter().position(|&eta| eta == x[3]).unwrap_or(0);
    let eta = if e > 0 && e + 1 < n_eta {
        parabola_min(
            [ETA_GRID[e - 1], ETA_GRID[e], ETA_GRID[e + 1]],
            [row[e - 1], row[e], row[e + 1]],
        )
        .unwrap_or(x[3])
    } else {
        x[3]
    };
    let refined = problem.linear(ln_sigma.exp(), eta);
    let grid = problem.linear(x[0].exp(), x[3]);
    if refined.cost <= grid.cost {
        (
            refined.cost,
            [
                ln_sigma,
                refined.rho_s * eta_factor(eta),
                refined.rho_d,
                eta,
            ],
        )
    } else {
        (
            grid.cost,
            [x[0], grid.rho_s * eta_factor(x[3]), grid.rho_d, x[3]],
        )
    }
}

/// Abscissa of the minimum of the parabola through three points, if it opens upwards and
/// the minimum lies between the outer points.
fn parabola_min(x: [f64; 3], y: [f64; 3]) -> Option<f64> {
    let d1 = (y[1] - y[0]) / (x[1] - x[0]);
    let d2 = (y[2] - y[1]) / (x[2] - x[1]);
    let curvature = (d2 - d1) / (x[2] - x[0]);
    if !(curvature > 0.0) {
        return None;
    }
    let m = 0.5 * (x[0] + x[1]) - d1 / (2.0 * curvature);
    (m > x[0] && m < x[2]).then_some(m)
}

/// The end of one Levenberg–Marquardt run.
#[derive(Clone, Copy, Debug)]
pub(super) struct LmOutcome {
    pub x: [f64; 4],
    pub cost: f64,
    pub iterations: usize,
    pub status: Status,
}

/// Solve the symmetric positive definite system m·x = b on the indices in `free`
/// (others get 0) by Cholesky; `None` if not positive definite.
fn solve_spd(m: &[[f64; 4]; 4], b: &[f64; 4], free: &[bool; 4]) -> Option<[f64; 4]> {
    let idx: Vec<usize> = (0..4).filter(|&i| free[i]).collect();
    let k = idx.len();
    let mut l = [[0.0; 4]; 4];
    for i in 0..k {
        for j in 0..=i {
            let mut s = m[idx[i]][idx[j]];
            for p in 0..j {
                s -= l[i][p] * l[j][p];
            }
            if i == j {
                if !(s > 0.0) || !s.is_finite() {
                    return None;
                }
                l[i][i] = s.sqrt();
            } else {
                l[i][j] = s / l[j][j];
            }
        }
    }
    let mut y = [0.0; 4];
    for i in 0..k {
        let mut s = b[idx[i]];
        for p in 0..i {
            s -= l[i][p] * y[p];
        }
        y[i] = s / l[i][i];
    }
    let mut x = [0.0; 4];
    for i in (0..k).rev() {
        let mut s = y[i];
        for p in i + 1..k {
            s -= l[p][i] * x[p];
        }
        x[i] = s / l[i][i];
    }
    let mut out = [0.0; 4];
    for i in 0..k {
        out[idx[i]] = x[i];
    }
    Some(out)
}

/// Levenberg–Marquardt with Marquardt's diagonal scaling and bounds by an active set:
/// a parameter on a bound whose gradient points out of the box is held for that step.
pub(super) fn levenberg_marquardt(
    problem: &LeastSquaresProblem,
    x0: [f64; 4],
    fixed: [bool; 4],
    max_iterations: usize,
) -> LmOutcome {
    levenberg_marquardt_until(problem, x0, fixed, max_iterations, 0.0)
}

/// [`levenberg_marquardt`] that also stops as soon as the cost is at or below `good_enough`.
pub(super) fn levenberg_marquardt_until(
    problem: &LeastSquaresProblem,
    x0: [f64; 4],
    fixed: [bool; 4],
    max_iterations: usize,
    good_enough: f64,
) -> LmOutcome {
    let (lo, hi) = (lower_bounds(), upper_bounds());
    let mut x: [f64; 4] = std::array::from_fn(|i| x0[i].clamp(lo[i], hi[i]));
    let (mut cost, mut a, mut g) = problem.accumulate(&x, true);
    let mut lambda = 1e-3;
    for iteration in 1..=max_iterations {
        let free: [bool; 4] = std::array::from_fn(|i| {
            !fixed[i] && !((x[i] <= lo[i] && g[i] > 0.0) || (x[i] >= hi[i] && g[i] < 0.0))
        });
        if !free.iter().any(|&f| f) || cost <= good_enough {
            return LmOutcome {
                x,
                cost,
                iterations: iteration - 1,
                status: Status::Converged,
            };
        }
        let trace: f64 = (0..4).filter(|&i| free[i]).map(|i| a[i][i]).sum();
        let floor = 1e-12 * trace.max(f64::MIN_POSITIVE);
        loop {
            let mut m = a;
            for i in 0..4 {
                m[i][i] += lambda * a[i][i].max(floor);
            }
            let neg_g = [-g[0], -g[1], -g[2], -g[3]];
            let step = solve_spd(&m, &neg_g, &free);
            if let Some(step) = step {
                let x_new: [f64; 4] = std::array::from_fn(|i| (x[i] + step[i]).clamp(lo[i], hi[i]));
                let (cost_new, a_new, g_new) = problem.accumulate(&x_new, true);
                if cost_new.is_finite() && cost_new < cost {
                    let small_step =
                        (0..4).all(|i| (x_new[i] - x[i]).abs() <= 1e-10 * (x[i].abs() + 1e-8));
                    let small_decrease = cost - cost_new <= 1e-12 * cost;
                    x = x_new;
                    cost = cost_new;
                    a = a_new;
                    g = g_new;
                    lambda = (lambda * 0.1).max(1e-12);
                    if small_step || small_decrease {
                        return LmOutcome {
                            x,
                            cost,
                            iterations: iteration,
                            status: Status::Converged,
                        };
                    }
                    break;
                }
            }
            lambda *= 10.0;
            if lambda > 1e14 {
                // No downhill step however short: a (possibly bounded) minimum.
                return LmOutcome {
                    x,
                    cost,
                    iterations: iteration,
                    status: Status::Converged,
                };
            }
        }
    }
    LmOutcome {
        x,
        cost,
        iterations: max_iterations,
        status: Status::IterationLimit,
    }
}

/// Global search then local polish, on the full model.
pub(super) fn global_fit(problem: &LeastSquaresProblem, max_iterations: usize) -> LmOutcome {
    let mut best: Option<LmOutcome> = None;
    for seed in seeds(problem, 3) {
        let run = levenberg_marquardt(problem, seed, [false; 4], max_iterations);
        if best.as_ref().is_none_or(|b| run.cost < b.cost) {
            best = Some(run);
        }
    }
    // seeds() always returns at least one point (the grid is not empty).
    best.unwrap_or_else(|| {
        levenberg_marquardt(problem, [0.0, 1.0, 0.5, 1.5], [false; 4], max_iterations)
    })
}

impl LeastSquaresProblem {
    /// Whitened ∂f/∂δ0 per reading at x: the model's change when every θr moves by the
    /// arm offset. With a window it is exact for the window's mean: (1/a)·(spec(θr + a/2) −
    /// spec(θr − a/2)), the point model's specular part at the edges; without one a central
    /// difference of the point model.
    pub(crate) fn shift_column(&self, x: &[f64; 4]) -> Vec<f64> {
        let sigma = x[0].exp();
        // The edge formula holds for one uniform window; a response of several steps takes
        // the travel's central difference for every reading.
        let edge_window = self.response.filter(DetectorResponse::is_top_hat);
        match edge_window.map(|r| r.step_deg()) {
            Some(a) => {
                let h = 0.5 * a;
                let edges: Vec<(f64, f64)> = self
                    .offsets
                    .iter()
                    .map(|&o| {
                        (
                            model::lobe_with_derivative(o - h, sigma).0,
                            model::lobe_with_derivative(o + h, sigma).0,
                        )
                    })
                    .collect();
                let fresnel: Vec<f64> = self
                    .psis
                    .iter()
                    .map(|&(s2, c)| model::reduced_fresnel_with_derivative(s2, c, x[3]).0)
                    .collect();
                let p = params_of(x);
                self.points
                    .iter()
                    .map(|pt| {
                        if pt.span_deg > 0.0 {
                            return pt.sqrt_w * self.moving_shift_derivative(&p, pt);
                        }
                        let (l_lo, l_hi) = edges[pt.offset as usize];
                        let first = &self.pieces[pt.pieces.0 as usize];
                        let last = &self.pieces[pt.pieces.1 as usize - 1];
                        let (f_lo, f_hi) = (
                            fresnel[first.psi[0] as usize],
                            fresnel[last.psi[2] as usize],
                        );
                        pt.sqrt_w * x[1] * (f_hi * last.h[2] * l_hi - f_lo * first.h[0] * l_lo) / a
                    })
                    .collect()
            }
            None => {
                let p = params_of(x);
                let step = 1e-4;
                self.points
                    .iter()
                    .map(|pt| {
                        if pt.span_deg > 0.0 || self.response.is_some() {
                            return pt.sqrt_w * self.moving_shift_derivative(&p, pt);
                        }
                        let (ti, tr) = (pt.geometry.theta_i_deg, pt.geometry.theta_r_deg);
                        let up = model::evaluate(&p, &PlaneGeometry::new(ti, tr + step), None).0;
                        let down = model::evaluate(&p, &PlaneGeometry::new(ti, tr - step), None).0;
                        pt.sqrt_w * (up - down) / (2.0 * step)
                    })
                    .collect()
            }
        }
    }

    /// ∂f/∂δ0 of a reading taken while the detector moved: a central difference of its
    /// mean over the travel (model::evaluate_reading), the travel moving with the zero.
    fn moving_shift_derivative(&self, p: &Params, pt: &Point) -> f64 {
        let step = 1e-4;
        let (ti, tr) = (pt.geometry.theta_i_deg, pt.geometry.theta_r_deg);
        let at = |d: f64| {
            model::evaluate_reading_through(p, ti, tr + d, pt.span_deg, self.response.as_ref()).0
        };
        (at(step) - at(-step)) / (2.0 * step)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::analysis::model::{RHO_S, SIGMA};

    fn grid() -> Vec<Observation> {
        let mut out = Vec::new();
        for ti in [20.0, 30.0, 45.0, 60.0] {
            for k in 0..=140 {
                let tr = 0.5 * k as f64;
                out.push(Observation {
                    theta_i_deg: ti,
                    theta_r_deg: tr,
                    radiance_factor: 1.0 + tr * 1e-3,
                    std: Some(0.01),
                    theta_r_span_deg: 0.0,
                });
            }
        }
        out
    }

    /// The public model's value and gradient of one reading, the arm offset `shift` added.
    type ModelOf = fn(&Params, &Observation, f64, Option<f64>) -> (f64, [f64; 4]);

    /// Assert that the engine's tables give `model`'s values and gradients for `obs` at each
    /// of `params`, with and without the window, with and without an arm offset, and that
    /// the shift column is the difference of the engine's own values.
    fn assert_engine_matches(obs: &[Observation], params: &[Params], model: ModelOf) {
        for acceptance in [None, Some(1.0)] {
            for shift in [0.0, 0.3] {
                let problem = LeastSquaresProblem::new(obs, &[], acceptance, shift);
                for p in params {
                    let x = x_of(p);
                    let values = problem.values(&x);
                    let (_, jac) = problem.rows(&x);
                    for (k, o) in obs.iter().enumerate() {
                        let (v, g) = model(p, o, shift, acceptance);
                        assert!(
                            (values[k] - v).abs() <= 1e-12 * v.abs(),
                            "{acceptance:?} {shift} {p:?} {o:?}: {} vs {v}",
                            values[k]
                        );
                        // x = (ln σ, A, ρd, η): ∂/∂ln σ = σ ∂/∂σ, ∂/∂A = ∂/∂ρs / (η²−1).
                        let want_sigma = g[SIGMA] * p.sigma_deg / 0.01;
                        let want_a = g[RHO_S] / eta_factor(p.eta) / 0.01;
                        assert!(
                            (jac[k][0] - want_sigma).abs() <= 1e-9 * (want_sigma.abs() + 1e-6),
                            "σ {o:?}: {} vs {want_sigma}",
                            jac[k][0]
                        );
                        assert!(
                            (jac[k][1] - want_a).abs() <= 1e-9 * (want_a.abs() + 1e-6),
                            "A {o:?}: {} vs {want_a}",
                            jac[k][1]
                        );
                    }
                    // The shift column against a difference of the engine's own values.
                    let column = problem.shift_column(&x);
                    let h = 1e-4;
                    let up = LeastSquaresProblem::new(obs, &[], acceptance, shift + h).values(&x);
                    let down = LeastSquaresProblem::new(obs, &[], acceptance, shift - h).values(&x);
                    for k in 0..obs.len() {
                        let fd = (up[k] - down[k]) / (2.0 * h) / 0.01;
                        assert!(
                            (column[k] - fd).abs() <= 1e-3 * (fd.abs() + 1.0),
                            "{acceptance:?} {p:?} reading {k}: {} vs {fd}",
                            column[k]
                        );
                    }
                }
            }
        }
    }

    /// G (σ 0.8°) and rough-II (σ 21.7°) of Table 6.
    const G_AND_ROUGH: [Params; 2] = [
        Params {
            sigma_deg: 0.8,
            rho_s: 57.8,
            rho_d: 0.855,
            eta: 1.19,
        },
        Params {
            sigma_deg: 21.7,
            rho_s: 0.409,
            rho_d: 0.414,
            eta: 2.5,
        },
    ];

    /// The engine's tables give the public model's values and gradients, with and without
    /// the window, with and without an arm offset, at σ on both sides of the moments'
    /// two evaluation methods.
    #[test]
    fn engine_matches_the_model() {
        let narrow = Params {
            sigma_deg: 0.3,
            rho_s: 40.0,
            rho_d: 0.8,
            eta: 1.19,
        };
        let params = [narrow, G_AND_ROUGH[0], G_AND_ROUGH[1]];
        assert_engine_matches(&grid(), &params, |p, o, shift, acceptance| {
            let geometry = PlaneGeometry::new(o.theta_i_deg, o.theta_r_deg + shift);
            model::evaluate(p, &geometry, acceptance)
        });
    }

    /// Readings taken while the detector moved (a sweep's bins, mixed with still ones): the
    /// engine's tables give the public model's mean over the travel, its gradient, and
    /// the shift column, with and without the window.
    #[test]
    fn engine_matches_the_model_for_bins() {
        let obs: Vec<Observation> = grid()
            .into_iter()
            .step_by(3)
            .enumerate()
            .map(|(k, o)| Observation {
                theta_r_span_deg: [0.0, 0.06, 0.3, 1.5][k % 4],
                ..o
            })
            .collect();
        assert_engine_matches(&obs, &G_AND_ROUGH, |p, o, shift, acceptance| {
            let (theta_i, theta_r) = (o.theta_i_deg, o.theta_r_deg + shift);
            model::evaluate_reading(p, theta_i, theta_r, o.theta_r_span_deg, acceptance)
        });
    }

    /// A measured response of several steps: the engine's values, σ-gradients and shift
    /// column are the model's through the same response (still and moving readings, with an
    /// offset), and a top-hat cut into equal steps is the top-hat.
    #[test]
    fn engine_matches_the_model_through_a_stepped_response() {
        let shares = [0.05, 0.12, 0.2, 0.26, 0.2, 0.12, 0.05];
        let response = DetectorResponse::from_steps(0.4, -1.25, &shares).unwrap();
        let obs: Vec<Observation> = grid()
            .into_iter()
            .step_by(5)
            .enumerate()
            .map(|(k, o)| Observation {
                theta_r_span_deg: [0.0, 0.3][k % 2],
                ..o
            })
            .collect();
        for shift in [0.0, 0.3] {
            let problem = LeastSquaresProblem::new(&obs, &[], Some(response), shift);
            for p in &G_AND_ROUGH {
                let x = x_of(p);
                let values = problem.values(&x);
                let (_, jac) = problem.rows(&x);
                let column = problem.shift_column(&x);
                for (k, o) in obs.iter().enumerate() {
                    let at = |d: f64| {
                        model::evaluate_reading_through(
                            p,
                            o.theta_i_deg,
                            o.theta_r_deg + shift + d,
                            o.theta_r_span_deg,
                            Some(&response),
                        )
                    };
                    let (v, g) = at(0.0);
                    assert!(
                        (values[k] - v).abs() <= 1e-12 * v.abs(),
                        "{o:?}: {} vs {v}",
                        values[k]
                    );
                    let want_sigma = g[SIGMA] * p.sigma_deg / 0.01;
                    assert!((jac[k][0] - want_sigma).abs() <= 1e-9 * (want_sigma.abs() + 1e-6));
                    let fd = (at(1e-4).0 - at(-1e-4).0) / 2e-4 / 0.01;
                    assert!((column[k] - fd).abs() <= 1e-6 * (fd.abs() + 1.0));
                }
            }
        }
        // Five steps of 0.2° with equal shares are the 1° top-hat (G's peak and flank), to
        // the parabola rule's own error on each (about 1e-6).
        let stepped = DetectorResponse::from_steps(0.2, -0.4, &[1.0; 5]).unwrap();
        for theta_r in [59.7, 60.0, 61.3, 63.0] {
            let whole = model::evaluate_reading(&G_AND_ROUGH[0], 60.0, theta_r, 0.0, Some(1.0)).0;
            let steps = model::evaluate_reading_through(
                &G_AND_ROUGH[0],
                60.0,
                theta_r,
                0.0,
                Some(&stepped),
            )
            .0;
            assert!(
                (whole - steps).abs() <= 1e-6 * whole,
                "{theta_r}: {whole} vs {steps}"
            );
        }
        let hat = DetectorResponse::top_hat(1.0);
        assert!((hat.variance_deg2() - 1.0 / 12.0).abs() < 1e-15);
        assert!((stepped.variance_deg2() - 1.0 / 12.0).abs() < 1e-12);
    }

    /// Woodbury: the engine's cost with shared errors equals rᵀ Σ⁻¹ r with Σ formed and
    /// inverted densely.
    #[test]
    fn shared_errors_give_the_dense_gls_cost() {
        let obs: Vec<Observation> = grid().into_iter().step_by(12).collect();
        let n = obs.len();
        let shared: Vec<SharedError> = (0..3)
            .map(|k| SharedError {
                name: format!("term {k}"),
                sensitivity: (0..n).map(|i| 0.01 * ((i * (k + 2)) % 7) as f64).collect(),
                additive: Vec::new(),
            })
            .collect();
        let p = Params {
            sigma_deg: 5.0,
            rho_s: 0.5,
            rho_d: 0.9,
            eta: 1.5,
        };
        let problem = LeastSquaresProblem::new(&obs, &shared, Some(1.0), 0.0);
        let cost = problem.accumulate(&x_of(&p), false).0;
        let mut sigma = Square::zeros(n);
        for i in 0..n {
            for j in 0..n {
                let shared_part: f64 = shared
                    .iter()
                    .map(|s| s.sensitivity[i] * s.sensitivity[j])
                    .sum();
                *sigma.at_mut(i, j) = shared_part + if i == j { 1e-4 } else { 0.0 };
            }
        }
        let inv = linalg::spd_inverse(&sigma).expect("positive definite");
        let values = problem.values(&x_of(&p));
        let r: Vec<f64> = values
            .iter()
            .zip(&obs)
            .map(|(f, o)| f - o.radiance_factor)
            .collect();
        let dense: f64 = (0..n)
            .map(|i| (0..n).map(|j| r[i] * inv.at(i, j) * r[j]).sum::<f64>())
            .sum();
        assert!((cost - dense).abs() <= 1e-9 * dense, "{cost} vs {dense}");
    }
}
