//! The TSL model against the published vectors, its derivatives against finite
//! differences, and its behaviour at the extremes.
use host::analysis::model::{self, Params};
use proptest::prelude::*;

fn vectors() -> Vec<(String, Params, f64, f64, f64)> {
    let text = include_str!("../data/tsl-vectors.csv");
    text.lines()
        .skip(1)
        .filter(|l| !l.trim().is_empty())
        .map(|line| {
            let f: Vec<&str> = line.split(',').collect();
            let num = |i: usize| f[i].trim().parse::<f64>().expect("vector file is numeric");
            let p = Params {
                sigma_deg: num(1),
                rho_s: num(2),
                rho_d: num(3),
                eta: num(4),
            };
            (f[0].to_string(), p, num(5), num(6), num(7))
        })
        .collect()
}

#[test]
fn matches_tsl_vectors_to_1e9_relative() {
    let v = vectors();
    assert_eq!(v.len(), 112, "8 papers × 14 geometries");
    for (name, p, ti, tr, expected) in v {
        let got = model::radiance_factor(&p, ti, tr);
        let rel = (got - expected).abs() / expected.abs();
        assert!(
            rel <= 1e-9,
            "{name} ({ti}, {tr}): {got} vs {expected} (rel {rel:e})"
        );
    }
}

/// Central difference with a step suited to each parameter.
fn finite_difference(p: &Params, ti: f64, tr: f64, index: usize) -> f64 {
    let base = p.to_array();
    let h = 1e-6 * base[index].abs().max(1e-3);
    let mut up = base;
    let mut down = base;
    up[index] += h;
    down[index] -= h;
    (model::radiance_factor(&Params::from_array(up), ti, tr)
        - model::radiance_factor(&Params::from_array(down), ti, tr))
        / (2.0 * h)
}

#[test]
fn analytic_derivatives_match_finite_differences() {
    let geometries = [
        (0.0, 0.0),
        (20.0, 21.0),
        (30.0, 33.0),
        (45.0, 46.5),
        (60.0, 62.0),
        (60.0, 70.0),
        (20.0, 0.0),
        (45.0, 30.0),
    ];
    let params = [
        Params {
            sigma_deg: 0.8,
            rho_s: 57.8,
            rho_d: 0.855,
            eta: 1.19,
        },
        Params {
            sigma_deg: 1.9,
            rho_s: 57.1,
            rho_d: 0.795,
            eta: 1.02,
        },
        Params {
            sigma_deg: 21.7,
            rho_s: 0.409,
            rho_d: 0.414,
            eta: 2.5,
        },
        Params {
            sigma_deg: 43.5,
            rho_s: 0.123,
            rho_d: 0.642,
            eta: 2.99,
        },
    ];
    for p in params {
        for (ti, tr) in geometries {
            let (value, grad) = model::radiance_factor_with_gradient(&p, ti, tr);
            for i in 0..4 {
                let fd = finite_difference(&p, ti, tr, i);
                let tol = 1e-6 * (fd.abs() + value.abs() * 1e-3) + 1e-12;
                assert!(
                    (grad[i] - fd).abs() <= tol,
                    "{p:?} ({ti},{tr}) d/d{}: analytic {} vs fd {fd}",
                    model::PARAM_NAMES[i],
                    grad[i]
                );
            }
        }
    }
}

#[test]
fn windowed_lobe_derivative_matches_finite_difference() {
    for sigma in [0.05, 0.3, 0.8, 1.9] {
        for offset in [0.0, 0.4, 1.0, 2.5, 6.0] {
            let (_, d) = model::windowed_lobe_with_derivative(offset, sigma, 1.0);
            let h = 1e-6 * sigma;
            let fd = (model::windowed_lobe_with_derivative(offset, sigma + h, 1.0).0
                - model::windowed_lobe_with_derivative(offset, sigma - h, 1.0).0)
                / (2.0 * h);
            assert!(
                (d - fd).abs() <= 1e-6 * (fd.abs() + 1e-6),
                "σ {sigma} offset {offset}: {d} vs {fd}"
            );
        }
    }
}

/// The matrix of the issue: every combination, θi and θr both over the angle set.
#[test]
fn finite_everywhere_on_the_extremes_matrix() {
    let sigmas = [1e-4, 0.01, 0.8, 45.0, 90.0];
    let etas = [1.0, 1.0 + 1e-9, 1.19, 3.0];
    let rho_ss = [0.0, 1e-9, 58.0, 1e4];
    let thetas = [0.0, 85.0, 89.99, 90.0];
    let mut checked = 0;
    for &sigma_deg in &sigmas {
        for &eta in &etas {
            for &rho_s in &rho_ss {
                let p = Params {
                    sigma_deg,
                    rho_s,
                    rho_d: 0.5,
                    eta,
                };
                for &ti in &thetas {
                    for &tr in &thetas {
                        let (v, g) = model::radiance_factor_with_gradient(&p, ti, tr);
                        assert!(v.is_finite() && v >= 0.5, "{p:?} ({ti},{tr}) = {v}");
                        assert!(
                            g.iter().all(|d| d.is_finite()),
                            "{p:?} ({ti},{tr}) gradient {g:?}"
                        );
                        for a in [0.5, 1.0] {
                            let w = model::observed_radiance_factor(&p, ti, tr, a);
                            assert!(w.is_finite(), "{p:?} ({ti},{tr}) acceptance {a}: {w}");
                        }
                        checked += 1;
                    }
                }
            }
        }
    }
    assert_eq!(checked, 5 * 4 * 4 * 16);
}

#[test]
fn normal_incidence_and_eta_one_limits() {
    // ψ = 0 exactly (θi = θr = 0): F = √2(η−1)/(η+1), computed, not 0/0.
    let p = Params {
        sigma_deg: 0.8,
        rho_s: 1.0,
        rho_d: 0.0,
        eta: 1.5,
    };
    let f = model::radiance_factor(&p, 0.0, 0.0);
    assert!((f - std::f64::consts::SQRT_2 * 0.5 / 2.5).abs() < 1e-15);
    // η = 1: no specular part at all, at any geometry.
    let p = Params {
        sigma_deg: 5.0,
        rho_s: 1e4,
        rho_d: 0.3,
        eta: 1.0,
    };
    for (ti, tr) in [(0.0, 0.0), (30.0, 30.0), (89.99, 89.99), (90.0, 90.0)] {
        assert_eq!(model::radiance_factor(&p, ti, tr), 0.3);
    }
    // η just above 1: F ∝ (η−1), smoothly.
    let f1 = model::fresnel(30.0, 1.0 + 1e-9);
    let f2 = model::fresnel(30.0, 1.0 + 2e-9);
    assert!(f1 > 0.0 && (f2 / f1 - 2.0).abs() < 1e-5, "{f1} {f2}");
    // ψ + δ = 90° (Brewster): the tan ratio vanishes, F = |sin ratio|.
    let eta: f64 = 1.5;
    let brewster = eta.atan().to_degrees();
    let p = brewster.to_radians();
    let d = (p.sin() / eta).asin();
    let sin_ratio = ((p - d).sin() / (p + d).sin()).abs();
    assert!((model::fresnel(brewster, eta) - sin_ratio).abs() < 1e-12);
}

#[test]
fn tiny_sigma_derivative_is_zero_not_nan() {
    let p = Params {
        sigma_deg: 1e-4,
        rho_s: 58.0,
        rho_d: 0.8,
        eta: 1.19,
    };
    let (v, g) = model::radiance_factor_with_gradient(&p, 45.0, 50.0);
    assert_eq!(v, 0.8);
    assert_eq!(g[model::SIGMA], 0.0);
}

proptest! {
    #[test]
    fn never_nan_in_range(
        sigma in 1e-4f64..90.0,
        rho_s in 0.0f64..1e4,
        rho_d in 0.0f64..10.0,
        eta in 1.0f64..3.0,
        ti in 0.0f64..=90.0,
        tr in 0.0f64..=90.0,
        acceptance in 0.0f64..2.0,
    ) {
        let p = Params { sigma_deg: sigma, rho_s, rho_d, eta };
        let (v, g) = model::radiance_factor_with_gradient(&p, ti, tr);
        prop_assert!(v.is_finite() && v >= rho_d);
        prop_assert!(g.iter().all(|d| d.is_finite()));
        let w = model::observed_radiance_factor(&p, ti, tr, acceptance);
        prop_assert!(w.is_finite() && w >= rho_d * (1.0 - 1e-12));
    }
}

/// The mean over a detector's travel of what it sees, by dense quadrature (4001 points,
/// Simpson): the reference the fit's travel nodes are held to.
fn dense_travel_mean(
    p: &Params,
    theta_i: f64,
    theta_r: f64,
    span: f64,
    acceptance: Option<f64>,
) -> f64 {
    let n = 4000;
    let h = span / n as f64;
    let mut sum = 0.0;
    for k in 0..=n {
        let weight = if k == 0 || k == n {
            1.0
        } else if k % 2 == 1 {
            4.0
        } else {
            2.0
        };
        let at = theta_r - 0.5 * span + k as f64 * h;
        sum += weight * model::evaluate(p, &model::PlaneGeometry::new(theta_i, at), acceptance).0;
    }
    sum * h / 3.0 / span
}

/// A sweep's bin, read while the detector arm moved: the model's mean over the travel
/// (through the acceptance window, or without one) agrees with dense quadrature for lobes
/// from the glossiest paper's to the roughest, bins from 0.05° to 3°, across the peak.
#[test]
fn a_bin_read_while_moving_is_the_mean_over_its_travel() {
    let papers = [
        (0.5, 60.0, 0.85, 1.2),
        (0.8, 57.8, 0.855, 1.19),
        (1.9, 57.1, 0.795, 1.02),
        (21.7, 0.409, 0.414, 3.0),
    ];
    let mut worst: f64 = 0.0;
    for (sigma_deg, rho_s, rho_d, eta) in papers {
        let p = Params {
            sigma_deg,
            rho_s,
            rho_d,
            eta,
        };
        for theta_i in [20.0, 45.0, 60.0] {
            for offset in [-3.0, -1.2, -0.4, 0.0, 0.3, 0.9, 2.5, 8.0] {
                for span in [0.05, 0.1, 0.25, 0.5, 1.0, 3.0] {
                    for acceptance in [Some(1.0), Some(0.5), None] {
                        let theta_r = theta_i + offset;
                        let got = model::evaluate_reading(&p, theta_i, theta_r, span, acceptance).0;
                        let want = dense_travel_mean(&p, theta_i, theta_r, span, acceptance);
                        let err = (got - want).abs() / want.abs().max(1e-3);
                        worst = worst.max(err);
                        assert!(
                            err < 2e-6,
                            "σ {sigma_deg} θi {theta_i} θr {theta_r} span {span} {acceptance:?}: {got} vs {want} ({err:e})"
                        );
                    }
                }
            }
        }
    }
    eprintln!("worst relative error of a bin's model: {worst:e}");
    // A still reading is the window's reading, exactly.
    let p = Params {
        sigma_deg: 0.8,
        rho_s: 57.8,
        rho_d: 0.855,
        eta: 1.19,
    };
    assert_eq!(
        model::evaluate_reading(&p, 60.0, 60.3, 0.0, Some(1.0)),
        model::evaluate(&p, &model::PlaneGeometry::new(60.0, 60.3), Some(1.0))
    );
}

/// The bin's gradient is the derivative of its value (central differences in each parameter).
#[test]
fn a_bins_gradient_is_the_derivative_of_its_value() {
    let p = Params {
        sigma_deg: 0.8,
        rho_s: 57.8,
        rho_d: 0.855,
        eta: 1.19,
    };
    for (span, acceptance) in [(0.3, Some(1.0)), (2.0, Some(1.0)), (0.4, None)] {
        let (_, g) = model::evaluate_reading(&p, 60.0, 60.6, span, acceptance);
        let h = [1e-6, 1e-5, 1e-6, 1e-6];
        for i in 0..4 {
            let at = |d: f64| {
                let mut q = p;
                match i {
                    0 => q.sigma_deg += d,
                    1 => q.rho_s += d,
                    2 => q.rho_d += d,
                    _ => q.eta += d,
                }
                model::evaluate_reading(&q, 60.0, 60.6, span, acceptance).0
            };
            let fd = (at(h[i]) - at(-h[i])) / (2.0 * h[i]);
            assert!(
                (g[i] - fd).abs() <= 1e-5 * (fd.abs() + 1e-3),
                "span {span} {acceptance:?} d/d{}: {} vs {fd}",
                model::PARAM_NAMES[i],
                g[i]
            );
        }
    }
}
