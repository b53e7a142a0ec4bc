//! Evidence: the paper's findings (Akao et al., Fig. 10 and its discussion) on synthetic
//! data with the issue's noise (1 % + 0.003) and the instrument's 1° acceptance.
use crate::common;
use host::analysis::classify::{Group, REFERENCES, classify};
use host::analysis::fit::{FitOptions, fit};
use host::analysis::sampling;

/// At M = 12 every group that is decided is right; a glossy paper may leave it undecided
/// (flagged `not-identified`), when η ends at its lower bound and ρs is then not determined
/// (SG's η = 1.02 is close to it) — it is never guessed.
#[test]
fn strategy1_m12_gets_every_group_right() {
    let geometries = common::strategy1_m12();
    let delta = sampling::delta(&geometries, None).expect("a known schedule");
    assert_eq!(delta.deg, 35.0);
    let mut decided_glossy = 0;
    for (k, r) in REFERENCES.iter().enumerate() {
        for seed in 0..3u64 {
            let obs = common::noisy(&r.params, &geometries, 500 + 10 * k as u64 + seed);
            let result = fit(&obs, &FitOptions::default()).expect("valid");
            let c = classify(&result);
            let check = sampling::check_sigma(result.sigma_deg(), delta.deg);
            println!(
                "M=12 {:4} seed {seed}: group {} class {} ({:.2}) σ {:?} ≤ {:?} σ_l {:.2} ok {} rd/rs {:.3}",
                r.name,
                c.group_name(),
                c.class_name(),
                c.confidence,
                result.sigma_deg(),
                result.sigma_upper_deg(),
                check.sigma_l_deg,
                check.sigma_ok,
                result.params.rho_d / result.params.rho_s
            );
            if r.class.group() == Group::Rough {
                assert_eq!(c.group, Some(Group::Rough), "{} seed {seed}", r.name);
            } else {
                assert!(
                    c.group.is_none_or(|g| g == Group::Glossy),
                    "{} seed {seed}: {:?}",
                    r.name,
                    c.group
                );
                assert!(
                    c.group.is_some() || !result.identified(host::analysis::model::RHO_S),
                    "{} seed {seed}: undecided without a reason",
                    r.name
                );
                decided_glossy += usize::from(c.group.is_some());
            }
            if r.class.group() == Group::Glossy {
                assert!(
                    !check.sigma_ok,
                    "{}: glossy papers fail the σ_l check at M = 12",
                    r.name
                );
            }
        }
    }
    assert!(
        decided_glossy >= 4,
        "the glossy group was decided in {decided_glossy} of 6 fits"
    );
}

#[test]
fn strategy1_m12_gets_the_rough_groups_right() {
    // The paper: the rough groups (by ρd/ρs) were right even from 12 geometries.
    let geometries = common::strategy1_m12();
    for (k, r) in REFERENCES
        .iter()
        .enumerate()
        .filter(|(_, r)| r.class.group() == Group::Rough)
    {
        let obs = common::noisy(&r.params, &geometries, 700 + k as u64);
        let c = classify(&fit(&obs, &FitOptions::default()).expect("valid"));
        assert_eq!(c.class, Some(r.class), "{}", r.name);
    }
}

/// (smallest δ that fails, largest δ that passes) for a paper, over Strategy 2's δ.
fn sigma_check_by_delta(name: &str, rel: f64, abs: f64, acceptance: f64) -> Vec<(u8, bool, f64)> {
    let p = common::reference(name);
    (1..=10u8)
        .map(|d| {
            let geometries = common::strategy2(d);
            let obs = common::synthetic(
                &p,
                &geometries,
                acceptance,
                rel,
                abs,
                900 + u64::from(d),
                false,
            );
            let options = FitOptions {
                acceptance_deg: (acceptance > 0.0).then_some(acceptance),
                ..FitOptions::default()
            };
            let result = fit(&obs, &options).expect("valid");
            let delta = sampling::delta(&geometries, None).expect("a known schedule");
            assert_eq!(delta.deg, f64::from(d));
            let check = sampling::check_sigma(result.sigma_deg(), delta.deg);
            (d, check.sigma_ok, result.sigma_deg().unwrap_or(f64::NAN))
        })
        .collect()
}

#[test]
fn glossy_papers_pass_the_sigma_l_check_after_strategy2() {
    for (name, largest_passing) in [("G", 3u8), ("SG", 8u8)] {
        // With the issue's noise and the instrument's window: passes at every δ up to the paper's.
        let noisy = sigma_check_by_delta(name, 0.01, 0.003, 1.0);
        println!("{name} noisy: {noisy:?}");
        for &(d, ok, sigma) in &noisy {
            if d <= largest_passing {
                assert!(ok, "{name} δ {d}: σ {sigma} should pass");
            }
        }
        // Noise-free, the boundary is exact: σ > σ_l exactly up to that δ.
        let exact = sigma_check_by_delta(name, 0.0, 0.0, 0.0);
        println!("{name} exact: {exact:?}");
        for &(d, ok, sigma) in &exact {
            assert_eq!(ok, d <= largest_passing, "{name} δ {d}: σ {sigma}");
        }
    }
}

/// J2 with a narrow specular bump on its lobe (the rise the paper saw on J1/J2): the fit
/// is flagged `lack-of-fit`, or else its intervals cover the truth; the class is never
/// wrong with confidence ≥ 0.95. Today: ρd +43 % with an interval of ±0.002 and no flag.
#[test]
fn a_specular_bump_is_flagged_or_honestly_bounded() {
    use common::{Instrument, Lobe, Sheet, covers, draw, truth};
    let p = common::reference("J2");
    let mut summary = Vec::new();
    for bump in [(0.3, 1.0), (0.1, 2.0)] {
        for (label, geometries) in [
            ("full grid", common::full_grid()),
            ("strategy 2, δ = 2°", common::strategy2(2)),
            ("M = 12", common::strategy1_m12()),
        ] {
            let instrument = Instrument::issue();
            let t = truth(
                &Sheet {
                    params: p,
                    lobe: Lobe::Gaussian,
                    bump: Some(bump),
                },
                &geometries,
                &instrument,
            );
            let (mut flagged, mut right) = (0, 0);
            let seeds = 10;
            for seed in 0..seeds {
                let (obs, _) = draw(&t, &instrument, 9000 + seed);
                let result = fit(&obs, &FitOptions::default()).expect("valid");
                let c = classify(&result);
                let truth = p.to_array();
                let honest = (0..3).all(|i| covers(result.ci95[i], truth[i]));
                assert!(
                    result.lack_of_fit || honest,
                    "bump {bump:?} {label} seed {seed}: unflagged and the intervals {:?} miss the truth {:?} (extension: terms and plausible members {:?}; estimates {:?})",
                    result.ci95,
                    truth,
                    result.extension.as_ref().map(|e| (&e.terms, &e.plausible)),
                    result.params
                );
                assert!(
                    !(c.class.is_some_and(|k| k != r_class("J2")) && c.confidence >= 0.95),
                    "bump {bump:?} {label} seed {seed}: confidently wrong"
                );
                flagged += usize::from(result.lack_of_fit);
                right += usize::from(c.class == Some(r_class("J2")));
            }
            summary.push(format!(
                "J2 + bump {bump:?} {label}: flagged {flagged}/{seeds}, class right {right}/{seeds}"
            ));
        }
    }
    println!("{}", summary.join("\n"));
}

fn r_class(name: &str) -> host::analysis::classify::Class {
    REFERENCES
        .iter()
        .find(|r| r.name == name)
        .expect("a Table 6 paper")
        .class
}
