//! The detector's angular acceptance: needed for narrow lobes, harmless for broad ones.
mod common;
use host::analysis::fit::{FitOptions, fit};

#[test]
fn glossy_sigma_is_recovered_with_the_acceptance_term() {
    let p = common::reference("G");
    let grid = common::full_grid();
    // Data as a 1° detector sees it (dense quadrature), with the noise.
    let obs = common::noisy(&p, &grid, 42);
    let with = fit(&obs, &FitOptions { acceptance_deg: Some(1.0), ..FitOptions::default() }).expect("valid");
    let without = fit(&obs, &FitOptions { acceptance_deg: None, ..FitOptions::default() }).expect("valid");
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
    let without = fit(&exact, &FitOptions { acceptance_deg: None, ..FitOptions::default() }).expect("valid");
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
        let without = fit(&obs, &FitOptions { acceptance_deg: None, ..FitOptions::default() }).expect("valid");
        assert_eq!(with.acceptance_deg, Some(1.0), "{name}: the window is always modelled");
        for i in 0..3 {
            let (a, b) = (with.params.to_array()[i], without.params.to_array()[i]);
            let u = with.std_error(i).expect("fitted");
            assert!((a - b).abs() < 0.1 * u, "{name} param {i}: {a} with the window, {b} without (u {u})");
        }
    }
}
