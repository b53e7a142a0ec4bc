//! The adaptive refinement policy: after Strategy 1, choose each next batch of geometries
//! from the current fit and its uncertainty, where a reading shrinks the uncertainty of σ
//! the most per second of device time (arm travel included), and stop when σ's interval
//! is within the target, the class is settled and the paper's σ_l criterion holds.
//!
//! The paper leaves adaptive placement as future work; this is a greedy sequential
//! optimal design. The information a reading at a geometry adds is its Fisher information
//! under the fitted model, jᵀj/s², with j the model's gradient there and s the predicted
//! standard uncertainty; the gain in σ is the drop of Var(σ) it brings (Sherman–Morrison
//! on the current inverse information). A batch is chosen greedily, each pick charged
//! its reading time plus the move from the previous pick.
//!
//! When Strategy 1 leaves σ unresolved (a glossy peak far narrower than its 35° spacing)
//! the gradient there means nothing, so the first batch is a probe instead: a ladder of
//! offsets around the specular direction at the incidence angle with the strongest peak,
//! which resolves any σ from a tenth of a degree to several degrees.

use crate::analysis::fit::{FitResult, Observation};
use crate::analysis::model::{self, PlaneGeometry, SIGMA};
use crate::session::order::Motion;
use protocol::Geometry;
use protocol::schedules::{INCIDENCE_DEG, THETA_R_MAX_DEG};
use std::collections::BTreeSet;

/// Targets and limits of the adaptive policy.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdaptiveTargets {
    /// Stop when the 95 % half-width of σ, relative to σ, is at most this.
    pub sigma_rel_half_width: f64,
    /// … and the class confidence is at least this.
    pub class_confidence: f64,
    /// Geometries per batch.
    pub batch: usize,
    /// Batches before giving up on the targets (the paper's policy then finishes).
    pub max_batches: usize,
}

impl Default for AdaptiveTargets {
    fn default() -> Self {
        // 1.96·SE ≤ 3 % leaves room for an underestimated SE against the 5 % goal.
        AdaptiveTargets { sigma_rel_half_width: 0.03, class_confidence: 0.95, batch: 6, max_batches: 8 }
    }
}

/// Candidate offsets from the specular direction, degrees: half a degree apart within
/// Strategy 2's ±10° window (finer than Strategy 2 at δ = 1°).
const CANDIDATE_STEP_DEG: f64 = 0.5;
const CANDIDATE_HALF_WIDTH_DEG: f64 = 10.0;

/// The probe's offsets from specular, degrees, on both sides.
const PROBE_OFFSETS_DEG: [f64; 4] = [0.5, 1.0, 2.0, 4.0];

/// Whether the fit pins σ down well enough to design on (else probe first).
pub fn sigma_resolved(fit: &FitResult) -> bool {
    match (fit.sigma_deg(), fit.std_error(SIGMA)) {
        (Some(sigma), Some(se)) => sigma > 0.0 && se.is_finite() && se < 0.5 * sigma,
        _ => false,
    }
}

/// Relative 95 % half-width of σ (1.96·SE/σ), if σ is resolved.
pub fn sigma_rel_half_width(fit: &FitResult) -> Option<f64> {
    let sigma = fit.sigma_deg()?;
    let se = fit.std_error(SIGMA)?;
    (sigma > 0.0 && se.is_finite()).then(|| 1.96 * se / sigma)
}

/// Every geometry the adaptive policy may choose, not yet measured.
pub fn candidates(measured: &BTreeSet<Geometry>) -> Vec<Geometry> {
    let n = (CANDIDATE_HALF_WIDTH_DEG / CANDIDATE_STEP_DEG).round() as i32;
    let mut out = Vec::new();
    for theta_i in INCIDENCE_DEG {
        for k in -n..=n {
            let theta_r = f64::from(theta_i) + f64::from(k) * CANDIDATE_STEP_DEG;
            if k == 0 || !(0.0..=f64::from(THETA_R_MAX_DEG)).contains(&theta_r) {
                continue;
            }
            if let Some(g) = Geometry::from_deg(f64::from(theta_i), theta_r) {
                if !measured.contains(&g) {
                    out.push(g);
                }
            }
        }
    }
    out
}

/// The probe batch: offsets ±0.5…4° around specular at the incidence angle whose
/// specular reading stands highest above the diffuse level.
pub fn probe(observations: &[Observation], measured: &BTreeSet<Geometry>) -> Vec<Geometry> {
    let diffuse = observations.iter().map(|o| o.radiance_factor).fold(f64::INFINITY, f64::min);
    let best = INCIDENCE_DEG
        .iter()
        .filter_map(|&ti| {
            let peak = observations.iter().find(|o| o.theta_i_deg == f64::from(ti) && o.theta_r_deg == f64::from(ti))?;
            Some((ti, peak.radiance_factor - diffuse))
        })
        .max_by(|a, b| a.1.total_cmp(&b.1))
        .map_or(INCIDENCE_DEG[INCIDENCE_DEG.len() / 2], |(ti, _)| ti);
    PROBE_OFFSETS_DEG
        .iter()
        .flat_map(|&d| [-d, d])
        .filter_map(|d| Geometry::from_deg(f64::from(best), f64::from(best) + d))
        .filter(|g| g.theta_r.deg() <= f64::from(THETA_R_MAX_DEG) && !measured.contains(g))
        .collect()
}

/// Predicted standard uncertainty of a reading of radiance factor `r`: s² = a² + (b·r)²,
/// fitted (non-negative least squares on the squares) to the readings taken.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NoiseModel {
    floor_sq: f64,
    relative_sq: f64,
}

impl NoiseModel {
    /// Fit to the observations that carry an uncertainty.
    pub fn fit(observations: &[Observation]) -> NoiseModel {
        let pts: Vec<(f64, f64)> = observations.iter().filter_map(|o| Some((o.radiance_factor * o.radiance_factor, o.std? * o.std?))).collect();
        let fallback = NoiseModel { floor_sq: 1e-6, relative_sq: 1e-4 };
        if pts.len() < 2 {
            return fallback;
        }
        // Least squares of s² on [1, r²], then clamped; failing that, one relative term.
        let (n, sx, sy, sxx, sxy) = pts.iter().fold((0.0, 0.0, 0.0, 0.0, 0.0), |(n, sx, sy, sxx, sxy), &(x, y)| (n + 1.0, sx + x, sy + y, sxx + x * x, sxy + x * y));
        let det = n * sxx - sx * sx;
        let (a, b) = if det.abs() > 1e-300 { ((sxx * sy - sx * sxy) / det, (n * sxy - sx * sy) / det) } else { (sy / n, 0.0) };
        let model = NoiseModel { floor_sq: a.max(1e-12), relative_sq: b.max(0.0) };
        if model.floor_sq.is_finite() && model.relative_sq.is_finite() { model } else { fallback }
    }

    /// Predicted variance at radiance factor `r`.
    pub fn variance(&self, r: f64) -> f64 {
        self.floor_sq + self.relative_sq * r * r
    }
}

/// The next batch by greedy sequential design from `here` (where the arms are), or `None`
/// when the fit gives no usable information matrix (then probe, or fall back).
pub fn next_batch(
    fit: &FitResult,
    observations: &[Observation],
    measured: &BTreeSet<Geometry>,
    here: Geometry,
    motion: &Motion,
    integration_ms: u32,
    batch: usize,
) -> Option<Vec<Geometry>> {
    let free = fit.model.0;
    if !free[SIGMA] {
        return None;
    }
    // Gradients over the fitted parameters only: the others are held, and carry no variance.
    let fitted_gradient = |theta_i_deg: f64, theta_r_deg: f64| {
        // As the fit modelled it: with the acceptance window exactly where the fit used one.
        let (value, g) = model::evaluate(&fit.params, &PlaneGeometry::new(theta_i_deg, theta_r_deg), fit.acceptance_deg);
        (value, std::array::from_fn::<f64, 4, _>(|i| if free[i] { g[i] } else { 0.0 }))
    };
    let noise = NoiseModel::fit(observations);
    let mut information = [[0.0; 4]; 4];
    for o in observations {
        let (value, j) = fitted_gradient(o.theta_i_deg, o.theta_r_deg);
        let s2 = o.std.map_or_else(|| noise.variance(value), |s| s * s).max(1e-18);
        for a in 0..4 {
            for b in 0..4 {
                information[a][b] += j[a] * j[b] / s2;
            }
        }
    }
    let mut cov = crate::analysis::fit::inverse_spd(&information, &free)?;
    let per_reading_s = motion.per_geometry_us(integration_ms) as f64 * 1e-6;
    let mut pool: Vec<(Geometry, [f64; 4], f64)> = candidates(measured)
        .into_iter()
        .map(|g| {
            let (value, j) = fitted_gradient(g.theta_i.deg(), g.theta_r.deg());
            (g, j, noise.variance(value).max(1e-18))
        })
        .collect();
    // cov·j and jᵀ·cov·j: what one more reading at j does to the covariance.
    let project = |cov: &[[f64; 4]; 4], j: &[f64; 4]| {
        let cj: [f64; 4] = std::array::from_fn(|a| (0..4).map(|b| cov[a][b] * j[b]).sum());
        let jcj: f64 = (0..4).map(|a| j[a] * cj[a]).sum();
        (cj, jcj)
    };
    let mut chosen = Vec::new();
    let mut at = here;
    while chosen.len() < batch && !pool.is_empty() {
        let mut best: Option<(usize, f64)> = None;
        for (k, (g, j, s2)) in pool.iter().enumerate() {
            let (cj, jcj) = project(&cov, j);
            // Sherman–Morrison: the drop of Var(σ) this reading brings.
            let gain = cj[SIGMA] * cj[SIGMA] / (s2 + jcj);
            let seconds = per_reading_s + motion.move_us(at, *g) as f64 * 1e-6;
            let score = gain / seconds;
            if score.is_finite() && best.is_none_or(|(_, b)| score > b) {
                best = Some((k, score));
            }
        }
        let (k, _) = best?;
        let (g, j, s2) = pool.swap_remove(k);
        let (cj, jcj) = project(&cov, &j);
        for a in 0..4 {
            for b in 0..4 {
                cov[a][b] -= cj[a] * cj[b] / (s2 + jcj);
            }
        }
        chosen.push(g);
        at = g;
    }
    (!chosen.is_empty()).then_some(chosen)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn candidates_skip_what_was_measured_and_stay_in_range() {
        let all = candidates(&BTreeSet::new());
        assert!(all.iter().all(|g| g.theta_r.deg() >= 0.0 && g.theta_r.deg() <= 70.0 && g.theta_r != g.theta_i));
        let measured: BTreeSet<Geometry> = all.iter().take(5).copied().collect();
        assert_eq!(candidates(&measured).len(), all.len() - 5);
    }

    #[test]
    fn noise_model_recovers_floor_and_relative_terms() {
        let obs: Vec<Observation> = [0.5, 1.0, 5.0, 20.0]
            .iter()
            .map(|&r| Observation { theta_i_deg: 20.0, theta_r_deg: 0.0, radiance_factor: r, std: Some((1e-6 + 1e-4 * r * r).sqrt()) })
            .collect();
        let m = NoiseModel::fit(&obs);
        assert!((m.variance(10.0) - (1e-6 + 1e-2)).abs() < 1e-9);
    }
}
