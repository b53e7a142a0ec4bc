//! Synthetic data for the tests: Table 6 papers on the method's schedules, with the
//! instrument's acceptance window (by dense quadrature, independent of the fit's closed
//! form) and seeded noise.
#![allow(dead_code)]
pub mod in_process;
mod seed;
use host::analysis::classify::REFERENCES;
use host::analysis::fit::{Observation, SharedError};
use host::analysis::model::{self, Params};
use protocol::schedules;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
pub use seed::run_seed;

/// (θi, θr) pairs of a protocol schedule.
pub fn pairs(s: &schedules::Schedule) -> Vec<(f64, f64)> {
    s.iter()
        .map(|g| (g.theta_i.deg(), g.theta_r.deg()))
        .collect()
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
    REFERENCES
        .iter()
        .find(|r| r.name == name)
        .expect("a Table 6 paper")
        .params
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
            let y = if std > 0.0 {
                (f + std * standard_normal(&mut rng)).max(0.0)
            } else {
                f
            };
            Observation {
                theta_i_deg: ti,
                theta_r_deg: tr,
                radiance_factor: y,
                std: with_std.then_some(std),
                theta_r_span_deg: 0.0,
            }
        })
        .collect()
}

/// The issue's noise: 1 % relative + 0.003 absolute.
pub fn noisy(p: &Params, geometries: &[(f64, f64)], seed: u64) -> Vec<Observation> {
    synthetic(
        p,
        geometries,
        model::DEFAULT_ACCEPTANCE_DEG,
        0.01,
        0.003,
        seed,
        false,
    )
}

/// The shape of a sheet's specular lobe in θa = |θr − θi|/2, 1 at θa = 0. All three have
/// the same FWHM as the TSL Gaussian exp(−θa²/(2σ²)) of the same σ; GGX and Cauchy have
/// the heavier tails real papers show.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Lobe {
    /// exp(−θa²/(2σ²)), the model's.
    Gaussian,
    /// Trowbridge–Reitz (GGX) microfacet distribution, D ∝ 1/(cos⁴θa (α² + tan²θa)²).
    Ggx,
    /// Lorentzian 1/(1 + (θa/γ)²).
    Cauchy,
}

/// Half width at half maximum in θa of the Gaussian lobe of σ, degrees.
pub fn lobe_hwhm_deg(sigma_deg: f64) -> f64 {
    sigma_deg * (2.0 * std::f64::consts::LN_2).sqrt()
}

/// GGX's α (radians) whose D/D(0) is ½ at θa = `hwhm_deg`, by bisection.
fn ggx_alpha(hwhm_deg: f64) -> f64 {
    let t = hwhm_deg.to_radians();
    let ratio = |alpha: f64| {
        alpha.powi(4) / (t.cos().powi(4) * (alpha * alpha + t.tan() * t.tan()).powi(2))
    };
    let (mut lo, mut hi) = (1e-6, 10.0);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if ratio(mid) < 0.5 { lo = mid } else { hi = mid }
    }
    0.5 * (lo + hi)
}

/// The lobe's value at θa (degrees) for the FWHM of σ.
pub fn lobe_value(lobe: Lobe, theta_a_deg: f64, sigma_deg: f64) -> f64 {
    match lobe {
        Lobe::Gaussian => (-0.5 * (theta_a_deg / sigma_deg).powi(2)).exp(),
        Lobe::Cauchy => 1.0 / (1.0 + (theta_a_deg / lobe_hwhm_deg(sigma_deg)).powi(2)),
        Lobe::Ggx => {
            let alpha = ggx_alpha(lobe_hwhm_deg(sigma_deg));
            let t = theta_a_deg.to_radians();
            alpha.powi(4) / (t.cos().powi(4) * (alpha * alpha + t.tan() * t.tan()).powi(2))
        }
    }
}

/// A simulated sheet: TSL parameters, the lobe's shape, and optionally a narrow specular
/// bump (amplitude relative to ρs, its σ in degrees) on top, like the rise the paper saw
/// on J1/J2.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sheet {
    pub params: Params,
    pub lobe: Lobe,
    pub bump: Option<(f64, f64)>,
}

impl Sheet {
    pub fn ideal(params: Params) -> Sheet {
        Sheet {
            params,
            lobe: Lobe::Gaussian,
            bump: None,
        }
    }

    /// Point radiance factor: ρs·F(ψ)·G/(cos θi cos θr)·(lobe + bump) + ρd.
    pub fn radiance_factor(&self, ti: f64, tr: f64) -> f64 {
        let p = &self.params;
        let g = model::PlaneGeometry::new(ti, tr);
        let theta_a = 0.5 * (tr - ti).abs();
        let f = model::fresnel(0.5 * (ti + tr), p.eta);
        let mut shape = lobe_value(self.lobe, theta_a, p.sigma_deg);
        if let Some((amplitude, sigma_b)) = self.bump {
            shape += amplitude * (-0.5 * (theta_a / sigma_b).powi(2)).exp();
        }
        p.rho_s * f * g.attenuation_over_cosines * shape + p.rho_d
    }

    /// As a detector of full acceptance `a` sees it at (θi, θr): 401 midpoints.
    pub fn seen(&self, ti: f64, tr: f64, a: f64) -> f64 {
        if a <= 0.0 {
            return self.radiance_factor(ti, tr);
        }
        let n = 401;
        (0..n)
            .map(|k| self.radiance_factor(ti, tr - 0.5 * a + a * (k as f64 + 0.5) / n as f64))
            .sum::<f64>()
            / n as f64
    }
}

/// The simulated instrument of the fit tests: detector window, noise sqrt((rel·f)² + abs²)
/// (attached as std when `with_std`), an arm zero offset (the detector is at θr + offset
/// when it says θr), and errors shared by readings: the white reading's at each θi
/// (relative `white_rel`) and the tile certificate's (relative `tile_rel`, all readings).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Instrument {
    pub acceptance_deg: f64,
    pub rel: f64,
    pub abs: f64,
    pub arm_offset_deg: f64,
    pub white_rel: f64,
    pub tile_rel: f64,
    pub with_std: bool,
}

impl Instrument {
    /// The issue's noise (1 % + 0.003) through the 1° window, nothing shared.
    pub fn issue() -> Instrument {
        Instrument {
            acceptance_deg: model::DEFAULT_ACCEPTANCE_DEG,
            rel: 0.01,
            abs: 0.003,
            arm_offset_deg: 0.0,
            white_rel: 0.0,
            tile_rel: 0.0,
            with_std: true,
        }
    }

    /// The simulated detector's level of noise (hil-sim at 100 ms: ~0.1–0.3 % relative, a
    /// read-noise floor of ~1e-3 on the ranges that carry a peak).
    pub fn quiet() -> Instrument {
        Instrument {
            rel: 0.003,
            abs: 0.001,
            ..Instrument::issue()
        }
    }
}

/// Noise-free readings of `sheet` at `geometries` as `instrument` sees them (window and arm
/// offset): compute once, then draw noise per seed with [`draw`].
pub fn truth(
    sheet: &Sheet,
    geometries: &[(f64, f64)],
    instrument: &Instrument,
) -> Vec<(f64, f64, f64)> {
    geometries
        .iter()
        .map(|&(ti, tr)| {
            (
                ti,
                tr,
                sheet.seen(
                    ti,
                    tr + instrument.arm_offset_deg,
                    instrument.acceptance_deg,
                ),
            )
        })
        .collect()
}

/// One measurement of `truth` with the instrument's noise and shared errors drawn from
/// `seed`, and the shared errors as the fit is told them (sensitivity = reading × relative
/// uncertainty, what a budget knows).
pub fn draw(
    truth: &[(f64, f64, f64)],
    instrument: &Instrument,
    seed: u64,
) -> (Vec<Observation>, Vec<SharedError>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut incidences: Vec<f64> = truth.iter().map(|t| t.0).collect();
    incidences.sort_by(f64::total_cmp);
    incidences.dedup();
    let white: Vec<f64> = incidences
        .iter()
        .map(|_| standard_normal(&mut rng))
        .collect();
    let tile = standard_normal(&mut rng);
    let obs: Vec<Observation> = truth
        .iter()
        .map(|&(ti, tr, f)| {
            let k = incidences.iter().position(|&t| t == ti).unwrap_or(0);
            let scaled =
                f * (1.0 + instrument.white_rel * white[k]) * (1.0 + instrument.tile_rel * tile);
            let std = (instrument.rel * f).hypot(instrument.abs);
            let y = (scaled + std * standard_normal(&mut rng)).max(0.0);
            Observation {
                theta_i_deg: ti,
                theta_r_deg: tr,
                radiance_factor: y,
                std: instrument.with_std.then_some(std),
                theta_r_span_deg: 0.0,
            }
        })
        .collect();
    let mut shared = Vec::new();
    if instrument.white_rel > 0.0 {
        for &theta_i in &incidences {
            let sensitivity = obs
                .iter()
                .map(|o| {
                    if o.theta_i_deg == theta_i {
                        o.radiance_factor * instrument.white_rel
                    } else {
                        0.0
                    }
                })
                .collect();
            shared.push(SharedError {
                name: format!("white θi = {theta_i}°"),
                sensitivity,
                additive: Vec::new(),
            });
        }
    }
    if instrument.tile_rel > 0.0 {
        shared.push(SharedError {
            name: "tile certificate".into(),
            sensitivity: obs
                .iter()
                .map(|o| o.radiance_factor * instrument.tile_rel)
                .collect(),
            additive: Vec::new(),
        });
    }
    (obs, shared)
}

/// Whether `value` lies in `interval`.
pub fn covers(interval: Option<(f64, f64)>, value: f64) -> bool {
    interval.is_some_and(|(lo, hi)| lo <= value && value <= hi)
}

/// The headless browser the page tests use, or `None` on a machine without one: the
/// README's test command passes on a fresh machine, and says loudly (on the terminal,
/// past the test harness's capture) which test it left out and how to run it. CI sets
/// `GONIO_REQUIRE_BROWSER=1` (`.ci/run`): there a missing browser fails the test.
pub fn chromium_or_skip() -> Option<std::path::PathBuf> {
    let required = std::env::var_os("GONIO_REQUIRE_BROWSER").is_some_and(|v| v == "1");
    browser_or_skip(host::output::chromium::find_chromium(), required)
}

/// [`chromium_or_skip`]'s decision: the browser `found`, else `None` with a notice, or a
/// panic when `required`.
pub fn browser_or_skip(
    found: Option<std::path::PathBuf>,
    required: bool,
) -> Option<std::path::PathBuf> {
    if found.is_some() {
        return found;
    }
    assert!(
        !required,
        "no chromium on PATH and GONIO_REQUIRE_BROWSER=1: install it (Debian: apt-get install chromium; .ci/run does)"
    );
    // Straight to the process's stderr: the harness captures eprintln! of a passing test.
    use std::io::Write;
    let _ = writeln!(
        std::io::stderr(),
        "\nNOTICE: no chromium on PATH: the report's headless-browser test is LEFT OUT on this machine (apt-get install chromium to run it; GONIO_REQUIRE_BROWSER=1 makes its absence a failure, as in CI)\n"
    );
    None
}
