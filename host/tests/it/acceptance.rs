//! The detector's angular acceptance: needed for narrow lobes, harmless for broad ones.
use crate::common;
use host::analysis::fit::{FitOptions, Observation, fit};

#[test]
fn glossy_sigma_is_recovered_with_the_acceptance_term() {
    let p = common::reference("G");
    let grid = common::full_grid();
    // Data as a 1° detector sees it (dense quadrature), with the issue's noise.
    let obs = common::noisy(&p, &grid, 42);
    let with = fit(
        &obs,
        &FitOptions {
            acceptance_deg: Some(1.0),
            ..FitOptions::default()
        },
    )
    .expect("valid");
    let without = fit(
        &obs,
        &FitOptions {
            acceptance_deg: None,
            ..FitOptions::default()
        },
    )
    .expect("valid");
    let err_with = with.params.sigma_deg / p.sigma_deg - 1.0;
    let err_without = without.params.sigma_deg / p.sigma_deg - 1.0;
    println!(
        "G, 1° acceptance: σ with the term {:.4}° ({:+.2} %), without {:.4}° ({:+.2} %)",
        with.params.sigma_deg,
        100.0 * err_with,
        without.params.sigma_deg,
        100.0 * err_without
    );
    assert_eq!(with.acceptance_deg, Some(1.0));
    assert!(err_with.abs() < 0.03, "with: {err_with}");
    // The term matters: leaving it out biases σ upwards (the window widens the peak).
    assert!(err_without > err_with.abs(), "without: {err_without}");

    // Noise-free, to show the bias alone.
    let exact = common::synthetic(&p, &grid, 1.0, 0.0, 0.0, 0, false);
    let with = fit(&exact, &FitOptions::default()).expect("valid");
    let without = fit(
        &exact,
        &FitOptions {
            acceptance_deg: None,
            ..FitOptions::default()
        },
    )
    .expect("valid");
    println!(
        "G, 1° acceptance, noise-free: σ error with the term {:+.3} %, without {:+.3} %",
        100.0 * (with.params.sigma_deg / p.sigma_deg - 1.0),
        100.0 * (without.params.sigma_deg / p.sigma_deg - 1.0)
    );
    assert!((with.params.sigma_deg / p.sigma_deg - 1.0).abs() < 0.005);
}

/// The window is modelled at every σ (no threshold that makes the estimator jump); for a
/// broad lobe it changes the readings by 1e-4 or less (the lobe and G/(cos·cos) both vary
/// little across 1°) and moves the parameters by well under their uncertainty.
#[test]
fn rough_papers_are_not_moved_by_it() {
    for name in ["PPC", "MC", "J1"] {
        let obs = common::noisy(&common::reference(name), &common::full_grid(), 7);
        let with = fit(&obs, &FitOptions::default()).expect("valid");
        let without = fit(
            &obs,
            &FitOptions {
                acceptance_deg: None,
                ..FitOptions::default()
            },
        )
        .expect("valid");
        assert_eq!(
            with.acceptance_deg,
            Some(1.0),
            "{name}: the window is always modelled"
        );
        for i in 0..3 {
            let (a, b) = (with.params.to_array()[i], without.params.to_array()[i]);
            let u = with.std_error(i).expect("fitted");
            assert!(
                (a - b).abs() < 0.1 * u,
                "{name} param {i}: {a} with the window, {b} without (u {u})"
            );
        }
    }
}

/// An arm zero offset of 0.3° in θr (the detector at θr + 0.3° when it says θr): the fit
/// detects it (likelihood-ratio test at 1 %), reports it with an interval, and σ stays
/// within its interval. Without the offset term σ moves and the fit is flagged (today σ
/// moves by −4.7 %, unflagged, χ²/ν 4174).
#[test]
fn an_arm_offset_is_detected_and_sigma_stays_in_its_interval() {
    use common::{Instrument, Sheet, covers, draw, truth};
    let mut summary = Vec::new();
    for name in ["G", "SG"] {
        for (label, geometries) in [
            ("full grid", common::full_grid()),
            ("strategy 2, δ = 2°", common::strategy2(2)),
        ] {
            let instrument = Instrument {
                arm_offset_deg: 0.3,
                ..Instrument::issue()
            };
            let p = common::reference(name);
            let t = truth(&Sheet::ideal(p), &geometries, &instrument);
            let seeds = 12;
            let (mut detected, mut offset_covered, mut sigma_covered, mut sigma_error) =
                (0, 0, 0, 0.0);
            for seed in 0..seeds {
                let (obs, _) = draw(&t, &instrument, 6000 + seed);
                let result = fit(&obs, &FitOptions::default()).expect("valid");
                let offset = result.arm_offset.expect("the offset is detected");
                detected += 1;
                offset_covered += usize::from(offset.ci95.0 <= 0.3 && 0.3 <= offset.ci95.1);
                sigma_covered += usize::from(covers(result.ci95[0], p.sigma_deg));
                sigma_error += (result.params.sigma_deg / p.sigma_deg - 1.0) / seeds as f64;
                assert!(
                    result
                        .notes
                        .iter()
                        .any(|n| matches!(n, host::analysis::fit::Note::ArmOffsetFitted { .. }))
                );
                assert!(
                    !result.lack_of_fit,
                    "{name} {label} seed {seed}: flagged with the offset fitted"
                );
                if seed == 0 {
                    // The paper's model without the offset term (an off-specular peak, one of
                    // the extensions, would take the offset up).
                    let without = fit(
                        &obs,
                        &FitOptions {
                            arm_offset: false,
                            extensions: false,
                            ..FitOptions::default()
                        },
                    )
                    .expect("valid");
                    summary.push(format!(
                        "{name} {label}: without the offset term σ {:+.2} %, χ²/ν {:.0}, flagged {}",
                        100.0 * (without.params.sigma_deg / p.sigma_deg - 1.0),
                        without.chi2.unwrap_or(f64::NAN) / without.dof as f64,
                        without.lack_of_fit
                    ));
                    assert!(
                        without.lack_of_fit,
                        "{name} {label}: the unmodelled offset is not flagged"
                    );
                }
            }
            summary.push(format!(
                "{name} {label}: detected {detected}/{seeds}, δ0 covered {offset_covered}, σ covered {sigma_covered}, mean σ error {:+.3} %",
                100.0 * sigma_error
            ));
            assert!(
                sigma_covered * 10 >= seeds as usize * 8,
                "{name} {label}: σ covered in {sigma_covered}/{seeds}"
            );
            assert!(
                offset_covered * 10 >= seeds as usize * 8,
                "{name} {label}: δ0 covered in {offset_covered}/{seeds}"
            );
            assert!(
                sigma_error.abs() < 0.005,
                "{name} {label}: σ biased by {sigma_error}"
            );
        }
    }
    println!("{}", summary.join("\n"));
}

/// The window's accuracy where the adaptive design measures (θi = 60°, 2–4° from
/// specular) and over the full grid: the fit's whole-model window against the exact mean
/// over the window (4000 midpoints), for every Table 6 paper; and what a fit of noise-free
/// windowed data returns. Today's centre-evaluated factors err by 0.3–0.6 % there.
#[test]
fn the_window_model_is_exact_to_far_below_the_noise() {
    use host::analysis::classify::REFERENCES;
    use host::analysis::model;
    let exact = |p: &model::Params, ti: f64, tr: f64| {
        let n = 4000;
        (0..n)
            .map(|k| model::radiance_factor(p, ti, tr - 0.5 + (k as f64 + 0.5) / n as f64))
            .sum::<f64>()
            / n as f64
    };
    let mut worst_near: f64 = 0.0;
    let mut worst_grid: f64 = 0.0;
    for r in &REFERENCES {
        for k in 0..=20 {
            let tr = 62.0 + 0.1 * k as f64;
            for tr in [tr, 120.0 - tr] {
                let e = exact(&r.params, 60.0, tr);
                worst_near = worst_near.max(
                    (model::observed_radiance_factor(&r.params, 60.0, tr, 1.0) / e - 1.0).abs(),
                );
            }
        }
        for (ti, tr) in common::full_grid() {
            let e = exact(&r.params, ti, tr);
            worst_grid = worst_grid
                .max((model::observed_radiance_factor(&r.params, ti, tr, 1.0) / e - 1.0).abs());
        }
    }
    println!(
        "window model vs exact: worst {:.2e} at θi 60°, 2–4° from specular; {:.2e} over the full grid",
        worst_near, worst_grid
    );
    assert!(
        worst_near <= 2e-5 && worst_grid <= 2e-5,
        "{worst_near} {worst_grid}"
    );
    // Noise-free data through the window: the fit returns σ to 1e-4.
    for name in ["G", "SG"] {
        let p = common::reference(name);
        let obs: Vec<Observation> = common::strategy2(2)
            .iter()
            .map(|&(ti, tr)| Observation {
                theta_i_deg: ti,
                theta_r_deg: tr,
                radiance_factor: exact(&p, ti, tr),
                std: Some(1e-3),
                theta_r_span_deg: 0.0,
            })
            .collect();
        let result = fit(&obs, &FitOptions::default()).expect("valid");
        let error = result.params.sigma_deg / p.sigma_deg - 1.0;
        println!(
            "{name} noise-free through the window: σ error {error:+.2e}, χ² {:.2e}",
            result.chi2.unwrap_or(f64::NAN)
        );
        assert!(error.abs() < 1e-4, "{name}: {error}");
    }
}

/// The simulated instrument (hil-sim) averages the scene over the window by 16-point
/// Gauss–Legendre; the fit's model agrees with it to the model's own error (≤ 2e-6), far
/// below the instrument's noise (1e-3) and the issue's 0.02 %.
#[test]
fn the_window_model_agrees_with_the_simulated_detector() {
    use hil_sim::detector::{Detector, DetectorParams};
    use host::analysis::model;
    let detector = Detector::new(DetectorParams::default(), 1);
    let mut worst: f64 = 0.0;
    for name in ["G", "SG"] {
        let p = common::reference(name);
        let scene = move |ti: f64, tr: f64| model::radiance_factor(&p, ti, tr);
        for k in 0..=20 {
            let tr = 62.0 + 0.1 * k as f64;
            let sim = detector.seen_radiance_factor(&scene, 60.0, tr);
            worst =
                worst.max((model::observed_radiance_factor(&p, 60.0, tr, 1.0) / sim - 1.0).abs());
        }
    }
    println!(
        "window model vs the simulator's detector at θi 60°, 2–4° from specular: worst {worst:.2e}"
    );
    assert!(worst <= 2e-6, "{worst}");
}
