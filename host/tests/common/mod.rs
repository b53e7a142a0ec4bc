//! Synthetic data for the tests: Table 6 papers on the method's schedules, with the
//! instrument's acceptance window (by dense quadrature, independent of the fit's closed
//! form) and seeded noise.
#![allow(dead_code)]
use host::analysis::classify::REFERENCES;
use host::analysis::fit::Observation;
use host::analysis::model::{self, Params};
use protocol::schedules;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// (θi, θr) pairs of a protocol schedule.
pub fn pairs(s: &schedules::Schedule) -> Vec<(f64, f64)> {
    s.iter().map(|g| (g.theta_i.deg(), g.theta_r.deg())).collect()
}

pub fn full_grid() -> Vec<(f64, f64)> {
    pairs(&schedules::full_grid())
}

pub fn strategy1_m12() -> Vec<(f64, f64)> {
    pairs(&schedules::strategy1(12).expect("M = 12 is in Table 4"))
}

pub fn strategy2(delta: u8) -> Vec<(f64, f64)> {
    pairs(&schedules::strategy2(delta).expect("δ in 1…10"))
}

pub fn reference(name: &str) -> Params {
    REFERENCES.iter().find(|r| r.name == name).expect("a Table 6 paper").params
}

/// The radiance factor a detector with a uniform window of full width `acceptance_deg`
/// sees: the point model averaged over 401 midpoints across the window.
pub fn windowed_truth(p: &Params, ti: f64, tr: f64, acceptance_deg: f64) -> f64 {
    if acceptance_deg <= 0.0 {
        return model::radiance_factor(p, ti, tr);
    }
    let n = 401;
    (0..n)
        .map(|k| {
            let x = tr - 0.5 * acceptance_deg + acceptance_deg * (k as f64 + 0.5) / n as f64;
            model::radiance_factor(p, ti, x)
        })
        .sum::<f64>()
        / n as f64
}

fn standard_normal(rng: &mut ChaCha8Rng) -> f64 {
    // Box–Muller; u1 in (0, 1].
    let u1: f64 = 1.0 - rng.random::<f64>();
    let u2: f64 = rng.random::<f64>();
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
}

/// Readings of `p` at `geometries` with the given acceptance and noise of standard
/// deviation sqrt((rel·f)² + abs²), clipped at 0; `with_std` attaches that std.
pub fn synthetic(
    p: &Params,
    geometries: &[(f64, f64)],
    acceptance_deg: f64,
    rel: f64,
    abs: f64,
    seed: u64,
    with_std: bool,
) -> Vec<Observation> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    geometries
        .iter()
        .map(|&(ti, tr)| {
            let f = windowed_truth(p, ti, tr, acceptance_deg);
            let std = (rel * f).hypot(abs);
            let y = if std > 0.0 { (f + std * standard_normal(&mut rng)).max(0.0) } else { f };
            Observation { theta_i_deg: ti, theta_r_deg: tr, radiance_factor: y, std: with_std.then_some(std) }
        })
        .collect()
}

/// The noise: 1 % relative + 0.003 absolute.
pub fn noisy(p: &Params, geometries: &[(f64, f64)], seed: u64) -> Vec<Observation> {
    synthetic(p, geometries, model::DEFAULT_ACCEPTANCE_DEG, 0.01, 0.003, seed, false)
}
