//! The fit's extension step (analysis/fit/extension): each term's false-alarm rate on the
//! paper's own model, with and without uncertainties, and each term found where the sheet
//! has it, with σ's interval covering the main lobe's half-maximum width.
//!
//! The sheets here are written out in the test (point functions averaged over the 1°
//! window by 401 midpoints), not taken from the fit's family: a Cauchy lobe, a Gaussian
//! haze, a width that changes with θi, a body with Fresnel transmission.
use crate::common::{self, Lobe, Sheet, covers, reference};
use host::analysis::fit::{FitOptions, FitResult, Observation, fit};
use host::analysis::flags::Flag;
use host::analysis::model::{self, Params, SIGMA};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The extensions on (they are off by default until the campaign's misses are fixed).
fn on() -> FitOptions {
    FitOptions {
        extensions: true,
        ..FitOptions::default()
    }
}

const PAPERS: [&str; 8] = ["G", "SG", "PPC", "MC", "J1", "J2", "J3", "J4"];

/// Readings of `truth` on the full grid through a 1° window, noise sqrt((1 % f)² + 0.003²).
fn readings(truth: &dyn Fn(f64, f64) -> f64, seed: u64, with_std: bool) -> Vec<Observation> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    common::full_grid()
        .into_iter()
        .map(|(ti, tr)| {
            let f = (0..401)
                .map(|k| truth(ti, tr - 0.5 + (k as f64 + 0.5) / 401.0))
                .sum::<f64>()
                / 401.0;
            let std = (0.01 * f).hypot(0.003);
            let z: f64 = rng.sample(rand_distr::StandardNormal);
            Observation {
                theta_i_deg: ti,
                theta_r_deg: tr,
                radiance_factor: (f + std * z).max(0.0),
                std: with_std.then_some(std),
                theta_r_span_deg: 0.0,
            }
        })
        .collect()
}

fn extended(r: &FitResult) -> Vec<&'static str> {
    r.extension
        .as_ref()
        .map(|e| e.terms.iter().map(|t| t.name).collect())
        .unwrap_or_default()
}

/// Point TSL with a Gaussian of σ; the body and the lobe replaceable.
fn tsl(p: Params) -> impl Fn(f64, f64) -> f64 {
    move |ti, tr| Sheet::ideal(p).radiance_factor(ti, tr)
}

#[test]
fn on_the_papers_own_model_a_term_is_added_at_the_stated_rate() {
    // 8 papers × 15 seeds, weighted and unweighted: 240 fits. Each term is tested at 0.3 %,
    // five terms: at most 1.5 % of fits extended if the levels hold; P(≥ 7 of 120 | 1.5 %)
    // is 0.3 %, so 6 of 120 is the bound asserted per kind. The shapes campaign
    // (docs/ACCURACY.md) counts it over sessions.
    for with_std in [true, false] {
        let mut extended_fits = Vec::new();
        for (k, paper) in PAPERS.iter().enumerate() {
            let truth = tsl(reference(paper));
            for seed in 0..15u64 {
                let obs = readings(&truth, 1000 * k as u64 + seed, with_std);
                let r = fit(&obs, &on()).expect("fit");
                if r.flags.contains(&Flag::ModelExtended) {
                    extended_fits.push(format!("{paper} seed {seed}: {:?}", extended(&r)));
                }
            }
        }
        assert!(
            extended_fits.len() <= 6,
            "with_std {with_std}: {} of 120 extended: {extended_fits:?}",
            extended_fits.len()
        );
    }
}

/// Over seeds: how often the term was added, and σ's interval covered `sigma_true`.
fn found(
    truth: &dyn Fn(f64, f64) -> f64,
    term: &str,
    sigma_true: f64,
    seeds: u64,
) -> (usize, usize, Vec<String>) {
    let (mut added, mut covered, mut seen) = (0, 0, Vec::new());
    for seed in 0..seeds {
        let obs = readings(truth, 77 + seed, true);
        let r = fit(&obs, &on()).expect("fit");
        let terms = extended(&r);
        added += usize::from(terms.contains(&term));
        covered += usize::from(covers(r.ci95[SIGMA], sigma_true));
        seen.push(format!(
            "{terms:?} σ {:.4} {:?}",
            r.params.sigma_deg, r.ci95[SIGMA]
        ));
    }
    (added, covered, seen)
}

#[test]
fn a_heavy_tailed_lobe_is_named_and_sigma_stays_its_half_maximum_width() {
    for paper in ["G", "SG"] {
        let p = reference(paper);
        let sheet = Sheet {
            params: p,
            lobe: Lobe::Cauchy,
            bump: None,
        };
        let truth = move |ti: f64, tr: f64| sheet.radiance_factor(ti, tr);
        let (added, covered, seen) = found(&truth, "lobe shape", p.sigma_deg, 6);
        assert!(added >= 5 && covered >= 5, "{paper}: {seen:#?}");
    }
}

#[test]
fn a_haze_lobe_is_named_and_the_main_lobe_reported() {
    let p = reference("G");
    // 3 % of the peak at σ 4°: the sheet that was reported rough-II.
    let haze = Params {
        sigma_deg: 4.0,
        rho_s: 0.03 * p.rho_s,
        rho_d: 0.0,
        eta: p.eta,
    };
    let truth = move |ti: f64, tr: f64| {
        model::radiance_factor(&p, ti, tr) + model::radiance_factor(&haze, ti, tr)
    };
    let (added, covered, seen) = found(&truth, "haze lobe", p.sigma_deg, 6);
    assert!(added >= 5 && covered >= 5, "{seen:#?}");
}

#[test]
fn a_width_that_changes_with_incidence_is_named() {
    // SG's σ from 2.3° at θi = 20° to 1.6° at 60° (the issue's), log-linear in θi.
    let p = reference("SG");
    let sigma_at = |ti: f64| (2.3_f64.ln() + (1.6_f64 / 2.3).ln() * (ti - 20.0) / 40.0).exp();
    let truth = move |ti: f64, tr: f64| {
        let q = Params {
            sigma_deg: sigma_at(ti),
            ..p
        };
        model::radiance_factor(&q, ti, tr)
    };
    let (added, covered, seen) = found(&truth, "σ varying with θi", sigma_at(45.0), 6);
    assert!(added >= 5 && covered >= 4, "{seen:#?}");
}

#[test]
fn a_body_falling_toward_grazing_is_named() {
    // MC (η inside its range) whose diffuse part falls as exp(−0.6·((1 − cos θi) + (1 − cos θr)))
    // relative to θi = θr = 45°: an Oren–Nayar-like body in the forward plane. (A body with
    // Fresnel transmission on J1 is fitted by η at its bound 3 within the noise and σ
    // 1.2 % low; that miss is in docs/ACCURACY.md, not hidden here.)
    let p = reference("MC");
    let q = |t: f64| 1.0 - t.to_radians().cos();
    let truth = move |ti: f64, tr: f64| {
        let specular = Params { rho_d: 0.0, ..p };
        model::radiance_factor(&specular, ti, tr)
            + p.rho_d * (-0.6 * (q(ti) + q(tr) - 2.0 * q(45.0))).exp()
    };
    let (added, covered, seen) = found(&truth, "non-Lambertian body", p.sigma_deg, 6);
    assert!(added >= 5 && covered >= 4, "{seen:#?}");
}

#[test]
fn a_body_behind_a_fresnel_interface_is_said_or_inside_the_interval() {
    // J1 whose diffuse part leaves through a Fresnel interface of η 1.5: it falls toward
    // grazing as (1 − R(θi))(1 − R(θr)), R the unpolarised reflectance; ρd is its value at
    // θi = θr = 45°. The paper's model takes it up with σ 1.2 % low and η at its bound.
    let p = reference("J1");
    let transmission = |t: f64| 1.0 - 0.5 * model::fresnel(t.abs(), 1.5).powi(2);
    let at_45 = transmission(45.0).powi(2);
    let truth = move |ti: f64, tr: f64| {
        let specular = Params { rho_d: 0.0, ..p };
        model::radiance_factor(&specular, ti, tr)
            + p.rho_d * transmission(ti) * transmission(tr) / at_45
    };
    let (mut said, mut seen) = (0, Vec::new());
    for seed in 0..6 {
        let r = fit(&readings(&truth, 300 + seed, true), &on()).expect("fit");
        let terms = extended(&r);
        let named = terms.iter().any(|t| t.contains("body"));
        said += usize::from(named || covers(r.ci95[SIGMA], p.sigma_deg));
        seen.push(format!(
            "{terms:?} σ {:.3} {:?}",
            r.params.sigma_deg, r.ci95[SIGMA]
        ));
    }
    // 4 of 6: where the term's test does not reach its level the model-form widening
    // covers σ only partly (docs/ACCURACY.md counts it).
    assert!(
        said >= 4,
        "unsaid and σ missed in {} of 6: {seen:#?}",
        6 - said
    );
}
