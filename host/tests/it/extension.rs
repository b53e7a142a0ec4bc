//! The fit's extension step (analysis/fit/extension): each term's false-alarm rate on the
//! paper's own model, with and without uncertainties, and each term found where the sheet
//! has it, with σ's interval covering the main lobe's half-maximum width.
//!
//! The sheets here are written out in the test (point functions averaged over the 1°
//! window by 401 midpoints), not taken from the fit's family: a Cauchy lobe, a Gaussian
//! haze, a width that changes with θi, a body with Fresnel transmission.
use crate::cli_support::{stderr, temp_dir};
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
    readings_on(&common::full_grid(), truth, seed, (0.01, 0.003), with_std)
}

/// Readings of `truth` at `geometries` through a 1° window, noise sqrt((relative·f)² +
/// floor²) for `noise` = (relative, floor).
fn readings_on(
    geometries: &[(f64, f64)],
    truth: &dyn Fn(f64, f64) -> f64,
    seed: u64,
    (relative, floor): (f64, f64),
    with_std: bool,
) -> Vec<Observation> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    geometries
        .iter()
        .map(|&(ti, tr)| {
            let f = (0..401)
                .map(|k| truth(ti, tr - 0.5 + (k as f64 + 0.5) / 401.0))
                .sum::<f64>()
                / 401.0;
            let std = (relative * f).hypot(floor);
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
    // eight terms: at most 2.4 % of fits extended if the levels hold (Bonferroni's bound;
    // less, for the statistics are correlated); P(≥ 8 of 120 | 2.4 %) is 0.9 %, so 7 of
    // 120 is the bound asserted per kind. The shapes campaign (docs/ACCURACY.md) counts it
    // over sessions.
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
            extended_fits.len() <= 7,
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
fn a_lobe_wider_past_its_peak_is_named_and_sigma_stays_its_half_maximum_width() {
    // Forward-scattering fibres: the lobe's σ twice as wide past its peak (toward
    // grazing) as before it, the two sides' widths averaging the paper's σ so that the
    // half-maximum width is the symmetric lobe's. G's 0.8° and J2's 17.9°: the campaign's
    // sheets that went undecided, or were reported with an arm offset that is not there.
    for paper in ["G", "J2"] {
        let p = reference(paper);
        let truth = move |ti: f64, tr: f64| {
            let side = if tr > ti { 2.0 } else { 1.0 };
            let q = Params {
                sigma_deg: p.sigma_deg * 2.0 * side / 3.0,
                ..p
            };
            model::radiance_factor(&q, ti, tr)
        };
        let (added, covered, seen) = found(&truth, "lobe wider on one side", p.sigma_deg, 6);
        assert!(added >= 5 && covered >= 5, "{paper}: {seen:#?}");
    }
}

#[test]
fn a_lobe_skewed_smoothly_leaves_sigma_inside_its_interval() {
    // Not the family's lobe: the width grows smoothly through the peak,
    // σ(θa) = σ·(1 + 0.4·tanh(θa/σ)), where the family's term splits it at the peak.
    // σ_eq is the half-maximum width, (θa₊ − θa₋)/(2·√(2 ln 2)), θa± where
    // θa = ±σ(θa)·√(2 ln 2) (iterated to a fixed point).
    let half = (2.0 * std::f64::consts::LN_2).sqrt();
    for paper in ["G", "J2"] {
        let p = reference(paper);
        let width = move |theta_a: f64| p.sigma_deg * (1.0 + 0.4 * (theta_a / p.sigma_deg).tanh());
        let half_max = |side: f64| {
            let mut theta_a = side * p.sigma_deg * half;
            for _ in 0..200 {
                theta_a = side * width(theta_a) * half;
            }
            theta_a
        };
        let sigma_eq = (half_max(1.0) - half_max(-1.0)) / (2.0 * half);
        let truth = move |ti: f64, tr: f64| {
            let q = Params {
                sigma_deg: width(0.5 * (tr - ti)),
                ..p
            };
            model::radiance_factor(&q, ti, tr)
        };
        let (_, covered, seen) = found(&truth, "lobe wider on one side", sigma_eq, 6);
        assert!(covered >= 5, "{paper}, σ_eq {sigma_eq}: {seen:#?}");
    }
}

#[test]
fn an_opposition_surge_is_named_and_sigma_stays_inside_its_interval() {
    // A body 60 % brighter at retro-reflection (phase angle g = θi + θr = 0), the surge a
    // Gaussian in g of 12°: not the family's exponential cusp. The full grid's θr ≥ 0 sees
    // only its flank (g ≥ 20°), at θr near 0 and the low θi.
    for paper in ["SG", "MC"] {
        let p = reference(paper);
        let truth = move |ti: f64, tr: f64| {
            let specular = Params { rho_d: 0.0, ..p };
            let g = (ti + tr) / 12.0;
            model::radiance_factor(&specular, ti, tr) + p.rho_d * (1.0 + 0.6 * (-0.5 * g * g).exp())
        };
        let (added, covered, seen) = found(&truth, "opposition surge", p.sigma_deg, 6);
        assert!(added >= 5 && covered >= 5, "{paper}: {seen:#?}");
    }
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

#[test]
fn a_fresnel_factor_flatter_than_the_models_never_gives_a_confident_wrong_class() {
    // G and SG whose lobes' Fresnel factor is flat, at its value at ψ = 45° (the shapes
    // campaign's fresnel-flat:1). The data want η beyond its bound 3, where ρs, the lobe's
    // amplitude over F(η), is tens of times below the paper's (SG: η 1.02, ρs 57.1): the
    // paper's tree then reads a glossy lobe as rough. A session (SG, adaptive, seed
    // 81039169) was classified rough-II at 1.00 with only `model-extended`. The class may
    // be wrong; never at confidence 0.95 (the test of a Fresnel factor flatter than the
    // model's flags it), and on SG, whose η is far from 3, the test says so wherever η
    // sits at 3.
    use host::analysis::classify::{class_of, classify};
    use host::analysis::fit::Note;
    let run = common::run_seed();
    let mut seen = Vec::new();
    let (mut confidently_wrong, mut at_bound, mut said) = (0, 0, 0);
    for paper in ["G", "SG"] {
        let p = reference(paper);
        let flat = model::fresnel(45.0, p.eta);
        let truth = move |ti: f64, tr: f64| {
            let g = model::PlaneGeometry::new(ti, tr);
            let lobe = common::lobe_value(Lobe::Gaussian, 0.5 * (tr - ti).abs(), p.sigma_deg);
            p.rho_s * flat * g.attenuation_over_cosines * lobe + p.rho_d
        };
        let truth_class = class_of(Some(p.sigma_deg), p.rho_s, p.rho_d);
        for (seed, with_std) in (0..6u64).flat_map(|s| [(s, true), (s, false)]) {
            let r = fit(&readings(&truth, 100 * run + seed, with_std), &on()).expect("fit");
            let c = classify(&r);
            let wrong = c.class != Some(truth_class);
            confidently_wrong += usize::from(wrong && c.confidence >= 0.95);
            let note = r
                .notes
                .iter()
                .any(|n| matches!(n, Note::FresnelFlatterThanModel { .. }));
            if paper == "SG" && r.params.eta >= 3.0 - 1e-9 {
                at_bound += 1;
                said += usize::from(note && r.flags.contains(&Flag::LackOfFit));
            }
            seen.push(format!(
                "{paper} seed {seed} std {with_std}: {} at {:.2}, η {:.2}, ρs {:.3}, {:?} {:?} said {note}",
                c.class_name(),
                c.confidence,
                r.params.eta,
                r.params.rho_s,
                extended(&r),
                r.flags
            ));
        }
    }
    eprintln!("flat-Fresnel SG fits with η at 3: {at_bound} of 12, said in {said}");
    assert_eq!(confidently_wrong, 0, "{seen:#?}");
    // η pins at 3 on SG's flat factor (12 of 12 when this was written): the count is
    // not left to be 0.
    assert!(at_bound >= 6, "{seen:#?}");
    assert_eq!(said, at_bound, "{seen:#?}");
}

/// `gonio measure ARGS --spots 1` with the extensions on (the variable set for the child
/// alone: the tests' process keeps its environment), its session.json.
fn session_with_extensions(name: &str, args: &[&str]) -> serde_json::Value {
    let dir = temp_dir("extension", name);
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_gonio"))
        .args(["measure", "--spots", "1", "--out"])
        .arg(&dir)
        .args(args)
        .env("GONIO_MODEL_EXTENSIONS", "1")
        .stdin(std::process::Stdio::null())
        .output()
        .expect("run gonio");
    let text = std::fs::read_to_string(dir.join("session.json"))
        .unwrap_or_else(|e| panic!("{name} {args:?}: no session.json ({e}): {}", stderr(&out)));
    let _ = std::fs::remove_dir_all(&dir);
    serde_json::from_str(&text).expect("session.json is JSON")
}

/// What a session's result says: its class, confidence, flags and whether the test of a
/// Fresnel factor flatter than the model's fired.
struct Said {
    class: String,
    confidence: f64,
    flags: Vec<String>,
    fresnel_flatter: bool,
    eta: f64,
}

fn said(session: &serde_json::Value) -> Said {
    let r = &session["result"];
    let strings = |v: &serde_json::Value| -> Vec<String> {
        v.as_array()
            .map(|a| {
                a.iter()
                    .filter_map(|x| x.as_str().map(String::from))
                    .collect()
            })
            .unwrap_or_default()
    };
    Said {
        class: r["class"].as_str().unwrap_or("undecided").to_string(),
        confidence: r["class_confidence"].as_f64().unwrap_or(0.0),
        flags: strings(&r["flags"]),
        fresnel_flatter: r["notes"].as_array().is_some_and(|notes| {
            notes
                .iter()
                .any(|n| n["kind"] == "fresnel_flatter_than_model")
        }),
        eta: r["eta"].as_f64().unwrap_or(f64::NAN),
    }
}

impl std::fmt::Display for Said {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} at {:.2}, η {:.3}, flags {:?}, η-bound test fired: {}",
            self.class, self.confidence, self.eta, self.flags, self.fresnel_flatter
        )
    }
}

#[test]
fn a_flat_fresnel_semi_gloss_session_is_flagged_not_confidently_wrong() {
    // The session (seed 81039169) and one of this run's: a semi-gloss whose
    // Fresnel factor is flat was classified rough-II at 1.00 with η pinned at 3 and ρs
    // 1.59 against 57.1. Now its class, if wrong, is flagged and below 0.95; on the
    // issue's seed the η-bound test is what says it.
    let sg = host::analysis::classify::REFERENCES
        .iter()
        .find(|r| r.name == "SG")
        .expect("SG")
        .class
        .name();
    for (k, seed) in [81_039_169, common::run_seed()].into_iter().enumerate() {
        let seed = seed.to_string();
        let session = session_with_extensions(
            &format!("flat-sg-{k}"),
            &[
                "--sim",
                "SG",
                "--departure",
                "fresnel-flat:1",
                "--policy",
                "adaptive",
                "--seed",
                &seed,
            ],
        );
        let s = said(&session);
        let flagged = s.flags.iter().any(|f| f == "lack-of-fit");
        assert!(
            s.class == sg || (flagged && s.confidence < 0.95),
            "seed {seed}: {s}"
        );
        if k == 0 {
            assert!(s.fresnel_flatter && flagged, "the issue's seed: {s}");
        }
    }
}

#[test]
fn on_exact_rough_papers_whose_eta_sits_at_3_the_eta_bound_test_fires_at_its_rate() {
    // The rough papers' η is 3, the model's bound, in the paper's own fits (Table 6): on
    // their exact TSL sheets η free fits above 3 in about half the sessions, and the test
    // is then made. It fires in at most 0.3 % of sessions if its level holds (half-χ²
    // with the critical value at 0.6 %). 6 papers × 4 seeds × {adaptive, sweep}: 48
    // sessions, each on its own seed; P(≥ 3 of 48 | 0.3 %) = 0.05 %, so at most 2 firings are allowed (a rate
    // of 10 % would pass with probability 0.13).
    const PAPERS: [&str; 6] = ["PPC", "MC", "J1", "J2", "J3", "J4"];
    let run = common::run_seed();
    // A seed for each session: the binomial count below needs independent sessions. With
    // one seed per index for every paper, the rough papers' sweeps read the same
    // geometries with the same noise, and one draw counted up to six times (run 65706:
    // seed 65706002 fired on PPC, MC and J4 swept, the same before the extensions' latest
    // change; 3 of 48).
    let specs: Vec<(&str, &str, u64)> = PAPERS
        .iter()
        .enumerate()
        .flat_map(|(k, p)| {
            ["adaptive", "sweep"]
                .into_iter()
                .enumerate()
                .flat_map(move |(j, policy)| {
                    (0..4u64).map(move |i| (*p, policy, 100 * j as u64 + 10 * k as u64 + i))
                })
        })
        .map(|(p, policy, i)| (p, policy, 1000 * run + i))
        .collect();
    let threads = std::thread::available_parallelism()
        .map_or(2, |n| n.get())
        .min(4);
    let rows: Vec<String> = std::thread::scope(|scope| {
        let handles: Vec<_> = specs
            .chunks(specs.len().div_ceil(threads))
            .enumerate()
            .map(|(t, chunk)| {
                scope.spawn(move || {
                    chunk
                        .iter()
                        .enumerate()
                        .map(|(k, (paper, policy, seed))| {
                            let seed_text = seed.to_string();
                            let s = said(&session_with_extensions(
                                &format!("rough-{t}-{k}"),
                                &["--sim", paper, "--policy", policy, "--seed", &seed_text],
                            ));
                            format!(
                                "{} {paper} {policy} seed {seed}: {s}",
                                if s.fresnel_flatter { "FIRED" } else { "-" }
                            )
                        })
                        .collect::<Vec<_>>()
                })
            })
            .collect();
        handles
            .into_iter()
            .flat_map(|h| h.join().expect("a worker"))
            .collect()
    });
    assert_eq!(rows.len(), 48);
    let fired = rows.iter().filter(|r| r.starts_with("FIRED")).count();
    eprintln!("η-bound test fired in {fired} of {} sessions", rows.len());
    assert!(fired <= 2, "{fired} of 48: {rows:#?}");
}

/// σ's 95 % interval in a session's result, where it has one.
fn sigma_interval(result: &serde_json::Value) -> Option<(f64, f64)> {
    let a = result["ci95"]["sigma_deg"].as_array()?;
    Some((a.first()?.as_f64()?, a.get(1)?.as_f64()?))
}

/// Single-spot sessions with the extensions on, one per (paper, sheet, policy), the sheet
/// as `gonio measure` options ("--departure haze:0.03:90"), on this run's seed: how many
/// have σ's interval holding the paper's σ, and what each said. Each interval must stay
/// within `factor` of σ (covered, not by giving σ up).
fn sessions_cover_sigma(cases: &[(&str, &str, &str)], factor: f64) -> (usize, Vec<String>) {
    let seed = common::run_seed().to_string();
    let mut seen = Vec::new();
    let mut covered = 0;
    for &(paper, sheet, policy) in cases {
        let sigma_eq = reference(paper).sigma_deg;
        let mut args = vec!["--sim", paper, "--policy", policy, "--seed", &seed];
        args.extend(sheet.split_whitespace());
        let name = format!("{paper}-{sheet}-{policy}").replace([' ', ':'], "_");
        let session = session_with_extensions(&name, &args);
        let r = &session["result"];
        let interval = sigma_interval(r);
        covered += usize::from(covers(interval, sigma_eq));
        if let Some((lo, hi)) = interval {
            assert!(
                lo > sigma_eq / factor && hi < sigma_eq * factor,
                "{paper} {sheet} {policy} seed {seed}: [{lo}, {hi}]"
            );
        }
        seen.push(format!(
            "{paper} {sheet} {policy} seed {seed}: σ {} {interval:?} against {sigma_eq}, flags {}",
            r["sigma_deg"], r["flags"]
        ));
    }
    (covered, seen)
}

#[test]
fn a_body_outside_the_family_leaves_sigma_inside_its_interval_on_rough_papers() {
    // J3 and PPC with a strong Oren–Nayar body and a Lommel–Seeliger (grazing) body, swept:
    // no member of the family has either body. The non-Lambertian body's term takes it up
    // and σ, traded against the body on a lobe as broad as a rough paper's, moved 3–11 %
    // with intervals of ± 0.3–0.7 % (the shapes campaign before the widening for shapes the
    // family does not hold: 0 of these 8 sessions of seeds 0–1 covered, all unflagged at
    // confidence 1.00; docs/ACCURACY.md, issue 28). Now σ's interval holds σ_eq, the
    // paper's σ: at least 3 of the 4 sessions of this run's seed, each within a factor 2.
    let (covered, seen) = sessions_cover_sigma(
        &[
            ("J3", "--departure oren-nayar:30", "sweep"),
            ("J3", "--departure grazing:1", "sweep"),
            ("PPC", "--departure oren-nayar:30", "sweep"),
            ("PPC", "--departure grazing:1", "sweep"),
        ],
        2.0,
    );
    assert!(covered >= 3, "σ covered in {covered} of 4: {seen:#?}");
}

#[test]
fn a_haze_as_broad_as_the_body_leaves_sigma_inside_its_interval_on_rough_papers() {
    // J2 and J4 with the shapes campaign's strong haze (3 % of the peak at 5σ, at most
    // 90°), swept and adaptive: the best haze member sits at its width's narrowest bound,
    // a heavy tail is chosen or nothing, and σ came out 1.8–2.1 % high against intervals
    // of ± 0.7–1.0 % (held-out seeds 2–3 before the haze's width was profiled: 8 of these
    // 8 sessions missed, unflagged at confidence 1.00; docs/ACCURACY.md, issue 28). Now
    // σ's interval holds σ_eq: at least 3 of the 4 sessions of this run's seed, and not by
    // giving σ up (within a factor 1.15; over seeds 11–16, 24 of 24 covered, the widest
    // −7 %/+6 %).
    let (covered, seen) = sessions_cover_sigma(
        &[
            ("J2", "--departure haze:0.03:89.5", "sweep"),
            ("J2", "--departure haze:0.03:89.5", "adaptive"),
            ("J4", "--departure haze:0.03:90", "sweep"),
            ("J4", "--departure haze:0.03:90", "adaptive"),
        ],
        1.15,
    );
    assert!(covered >= 3, "σ covered in {covered} of 4: {seen:#?}");
}

#[test]
fn a_term_that_leaves_the_main_lobe_unidentified_is_not_chosen() {
    // The strong haze J2, swept, on the seed of a CI run of the test above (37726): a heavy
    // tail was added, then a haze whose width went to its bound, 30× the main lobe's
    // (520°, a pedestal under it), and that member's own intervals were reported: ρs
    // [0.15, 3.35], σ 17.35 [9.0, 33.4]° against 17.9°, unflagged. The widening never
    // counted a member that does not identify the main lobe; now one is not chosen either
    // where the model without its term did, and the tail's model and the haze's profile
    // give an interval that holds σ_eq within the factor the test above asks.
    let session = session_with_extensions(
        "haze-width-at-bound",
        &[
            "--sim",
            "J2",
            "--policy",
            "sweep",
            "--seed",
            "37726",
            "--departure",
            "haze:0.03:89.5",
        ],
    );
    let r = &session["result"];
    let terms: Vec<&str> = r["model_extension"]["terms"]
        .as_array()
        .map(|t| t.iter().filter_map(|t| t["name"].as_str()).collect())
        .unwrap_or_default();
    assert!(!terms.contains(&"haze lobe"), "{terms:?}: {r:#}");
    let interval = sigma_interval(r).expect("σ has an interval");
    let sigma_eq = reference("J2").sigma_deg;
    assert!(
        covers(Some(interval), sigma_eq)
            && interval.0 > sigma_eq / 1.15
            && interval.1 < sigma_eq * 1.15,
        "σ {interval:?} against {sigma_eq}"
    );
}

#[test]
fn a_mild_haze_or_one_fitted_to_nothing_leaves_sigma_inside_its_interval() {
    // A mild haze (1 % at 5σ) on J2, swept: every member's own χ² failed at 5 % (p 0.008,
    // not enough for `lack-of-fit`), so the haze's profile, as good as the best member,
    // was left out and σ 18.03 [17.98, 18.16] missed 17.9 unflagged. A strong haze on
    // PPC, adaptive: the profile's fraction fitted to 0 (a bound), so it counted not at
    // all, and σ 22.09 [21.92, 22.35] missed 21.7 (held-out seeds 2–3, docs/ACCURACY.md).
    // Now the members as good as the best are counted, and one at a bound by the side its
    // bounded term reaches: at least 3 of the 4 sessions of this run's seed covered,
    // within a factor 1.1 (seeds 11–16: 24 of 24, the widest −7.6 %/+5.7 %).
    let (covered, seen) = sessions_cover_sigma(
        &[
            ("J2", "--departure haze:0.01:89.5", "sweep"),
            ("J2", "--departure haze:0.01:89.5", "adaptive"),
            ("PPC", "--departure haze:0.03:90", "sweep"),
            ("PPC", "--departure haze:0.03:90", "adaptive"),
        ],
        1.1,
    );
    assert!(covered >= 3, "σ covered in {covered} of 4: {seen:#?}");
}

#[test]
fn a_haze_that_may_be_the_lobes_own_tail_leaves_sigma_inside_its_interval() {
    // A lobe half GGX, half Gaussian on SG (σ_eq 1.9°, the blend's half-maximum width) is
    // read by the family as a Student-t main lobe of σ 1.87° and a haze of 2–3 % at about
    // 6°: the sum of the two has the sheet's half-maximum width (1.90°), the main lobe
    // alone does not, and the readings cannot tell a haze from a tail (every other member
    // rejected). Adaptive seed 3 ended at 56 geometries with σ 1.8720 [1.8682, 1.8758],
    // unflagged at 1.00 (so did seed index 4 of the shapes campaign at 62). Now the
    // interval holds the sum's width as well as the main lobe's, for every member with a
    // haze: that session is covered and not by giving σ up (within 3 %); this run's seed's,
    // swept and adaptive, covered within a factor 1.5 (seeds 1–6 swept, the widest
    // [1.35, 2.38]: the members' spread there, not this rule).
    let session = session_with_extensions(
        "sg-ggx-blend-seed-3",
        &[
            "--sim",
            "SG",
            "--lobe",
            "ggx",
            "--lobe-weight",
            "0.5",
            "--policy",
            "adaptive",
            "--seed",
            "3",
        ],
    );
    let interval = sigma_interval(&session["result"]);
    assert!(
        covers(interval, 1.9)
            && interval.is_some_and(|(lo, hi)| lo > 1.9 / 1.03 && hi < 1.9 * 1.03),
        "σ {} {interval:?} against 1.9",
        session["result"]["sigma_deg"]
    );
    let (covered, seen) = sessions_cover_sigma(
        &[
            ("SG", "--lobe ggx --lobe-weight 0.5", "sweep"),
            ("SG", "--lobe ggx --lobe-weight 0.5", "adaptive"),
        ],
        1.5,
    );
    assert_eq!(covered, 2, "{seen:#?}");
}

#[test]
fn a_lobe_lighter_tailed_than_the_gaussian_leaves_sigma_inside_its_interval_on_mc() {
    // A Blinn–Phong lobe on MC (σ 43.5°): its tail is lighter than the Gaussian of the same
    // half width, the lobe-shape member goes to the lightest tail the family holds
    // (κ = −¼, σ 42.4) and was not counted (a term at a bound); the Gaussian gave 46.2
    // [43.7, 47.6] swept and 47.1 [44.0, 49.6] adaptive, unflagged at 1.00 (held-out seeds
    // 2–3). Now the bounded member counts by the side it reaches as the tail grows
    // (σ up from 42.4): at least 3 of the 4 sessions of this run's seed covered. MC's σ is
    // the least determined of the eight papers (lobe and body trade at σ 43.5°: ± 19–31 %
    // on exact TSL), so the intervals may reach σ's bound 90°: within a factor 3, which
    // guards against an interval that gives σ up (down to its floor), not a width (seeds
    // 11–16 reached a factor 2.1, seed 20828 swept [18.1, 81.8]°, 2.4). J4 with the same
    // lobe, the other rough papers' case, must be covered as before (seeds 11–16: MC 12 of
    // 12, J4 12 of 12).
    let (covered, seen) = sessions_cover_sigma(
        &[
            ("MC", "--lobe blinn-phong", "sweep"),
            ("MC", "--lobe blinn-phong", "adaptive"),
            ("J4", "--lobe blinn-phong", "sweep"),
            ("J4", "--lobe blinn-phong", "adaptive"),
        ],
        3.0,
    );
    assert!(covered >= 3, "σ covered in {covered} of 4: {seen:#?}");
}

#[test]
fn a_ggx_lobe_on_mc_leaves_sigma_inside_its_interval() {
    // A Trowbridge–Reitz (GGX) lobe on MC (σ 43.5°) read at the paper's twelve geometries
    // fits the paper's model as σ 36.4–36.9° with every member of the θa family within its
    // noise of it: these three seeds (adaptive, the shapes campaign's seed indices 5, 14,
    // 18) missed 43.5° unflagged at 1.00, σ's interval reaching 42.5–42.9°. GGX is a tail
    // of κ ⅓ in sin θa, a member the intervals now cover: all three covered, and this
    // run's seed, each within a factor 3 (MC's σ is the least determined of the papers).
    let sigma_eq = reference("MC").sigma_deg;
    let run_seed = common::run_seed().to_string();
    let mut seen = Vec::new();
    let mut missed = 0;
    for seed in ["554798412", "398428119", "132417198", &run_seed] {
        let args = [
            "--sim", "MC", "--lobe", "ggx", "--policy", "adaptive", "--seed", seed,
        ];
        let session = session_with_extensions(&format!("mc-ggx-{seed}"), &args);
        let r = &session["result"];
        let interval = sigma_interval(r);
        if let Some((lo, hi)) = interval {
            assert!(
                lo > sigma_eq / 3.0 && hi < sigma_eq * 3.0,
                "seed {seed}: [{lo}, {hi}]"
            );
        }
        missed += usize::from(!covers(interval, sigma_eq));
        seen.push(format!(
            "seed {seed}: σ {} {interval:?}, flags {}, not excluded: {}",
            r["sigma_deg"], r["flags"], r["model_extension"]["plausible"]
        ));
    }
    assert_eq!(missed, 0, "{seen:#?}");
    assert!(
        seen.iter().all(|s| s.contains("lobe shape of GGX")),
        "the GGX member is named among those not excluded: {seen:#?}"
    );
}

#[test]
fn a_beckmann_lobe_on_sg_is_the_lobe_shapes_kappa_below_zero() {
    // The swept Beckmann SGs that missed 1.9° (seeds 4–21 of the shapes campaign, σ 1.893
    // [1.889, 1.899]) are not a shape the family lacks: Beckmann's lobe on SG is the θa
    // family's κ ≈ −0.0015 (family.rs's unit test), which the paper's Gaussian reads 0.2 %
    // narrow. At a hundredth of the noise the readings tell the two apart: the lobe shape is
    // called for, named with a κ that shows its digits, and σ is 1.9° to 0.03 % (the paper's
    // model alone: 1.8962° on seed 134966875). At the campaign's noise the lobe shape's
    // member, κ free, covers 1.9° in 96.5 % of 200 swept sessions (docs/ACCURACY.md).
    let sigma_eq = reference("SG").sigma_deg;
    let run = common::run_seed().to_string();
    for seed in ["134966875", &run] {
        let args = [
            "--sim",
            "SG",
            "--lobe",
            "beckmann",
            "--policy",
            "sweep",
            "--noise-scale",
            "0.01",
            "--seed",
            seed,
        ];
        let session = session_with_extensions(&format!("sg-beckmann-{seed}"), &args);
        let r = &session["result"];
        let sigma = r["sigma_deg"].as_f64().expect("σ");
        let terms = &r["model_extension"]["terms"];
        let lobe = terms
            .as_array()
            .and_then(|t| t.iter().find(|t| t["name"] == "lobe shape"))
            .unwrap_or_else(|| panic!("seed {seed}: no lobe shape among {terms}"));
        let description = lobe["description"].as_str().unwrap_or_default();
        let kappa: f64 = description
            .split("κ = ")
            .nth(1)
            .and_then(|rest| rest.split(' ').next())
            .and_then(|k| k.parse().ok())
            .unwrap_or_else(|| panic!("seed {seed}: no κ in {description:?}"));
        assert!(
            (-0.002..=-0.001).contains(&kappa) && description.contains("lighter-tailed"),
            "seed {seed}: {description}"
        );
        assert!(
            (sigma / sigma_eq - 1.0).abs() < 3e-4,
            "seed {seed}: σ {sigma} against {sigma_eq} ({description})"
        );
    }
}

#[test]
fn rho_s_is_identified_as_the_reported_eta_interval_says() {
    // ρs = A/(η²−1) is unbounded where η's interval reaches 1. A term may fix η where the
    // paper's model could not: on the campaign's strong σ slope on J1 (adaptive, seed
    // 453077596) the paper's model had η 2.6 [1.0, 3.0], the slope's member η 2.98
    // [2.62, 3.00] and ρs [0.67, 0.83], yet ρs stayed "not identified" and the class
    // undecided. The converse is not drawn from the members' linear intervals. Whatever
    // the seed, ρs is called unbounded only where the η interval reported reaches 1, and
    // has an interval exactly where it is identified.
    let run = common::run_seed().to_string();
    let cases = [
        ("J1", "sigma-slope:-0.4", "453077596"),
        ("J1", "sigma-slope:-0.4", run.as_str()),
        ("J2", "sigma-slope:-0.4", run.as_str()),
        ("J2", "peak-shift:12.65", run.as_str()),
        ("MC", "retro:1:15", run.as_str()),
        ("J3", "retro:0.3:15", "854377566"),
    ];
    for (k, (paper, departure, seed)) in cases.into_iter().enumerate() {
        let session = session_with_extensions(
            &format!("eta-rho-s-{k}"),
            &[
                "--sim",
                paper,
                "--departure",
                departure,
                "--policy",
                "adaptive",
                "--seed",
                seed,
            ],
        );
        let r = &session["result"];
        let what = format!("{paper} {departure} seed {seed}: {}", said(&session));
        let rho_s_unknown = r["not_identified"]
            .as_array()
            .is_some_and(|a| a.iter().any(|u| u["param"] == "rho_s"));
        assert_eq!(
            r["ci95"]["rho_s"].is_array(),
            !rho_s_unknown,
            "{what}: ρs's interval {} with not_identified {}",
            r["ci95"]["rho_s"],
            r["not_identified"]
        );
        let unbounded = r["notes"]
            .as_array()
            .is_some_and(|a| a.iter().any(|n| n["kind"] == "rho_s_unbounded"));
        if let (true, Some(eta_lo)) = (unbounded, r["ci95"]["eta"][0].as_f64()) {
            assert!(
                eta_lo <= 1.0 + 1e-6,
                "{what}: ρs called unbounded where η's interval {} does not reach 1",
                r["ci95"]["eta"]
            );
        }
        // The campaign's two seeds: the slope fixed η (rough-I, J1's); a mild retro surge
        // on J3 (η 2.61 [1.00, 3.00] from the members' linear intervals, the paper's model
        // not calling ρs unbounded) keeps its class, rough-II.
        match k {
            0 => assert_eq!(r["class"], "rough-I", "{what}"),
            5 => assert_eq!(r["class"], "rough-II", "{what}"),
            _ => {}
        }
    }
}

#[test]
fn a_glossy_lobe_lost_to_a_body_rising_toward_grazing_is_found_again() {
    // G whose body is Lommel–Seeliger's (Lambert's at 45°/45°, 1.7× it at 60°/70°), on
    // the 26 geometries an adaptive session measured (seed 282527230 of the
    // shapes campaign's grazing:1), each reading sharing a tile error of 0.5 % and its
    // incidence's white of 0.2 % (and those at the peaks a gain ratio's 0.33 %). The paper's model cannot hold the body; with the shared
    // errors its fit took the misfit as a common scale error and ended at σ 90° with ρs
    // 0.3, its model a quarter of every reading: rough-II, though the readings at specular
    // were 18× the body. Every member the extension step started from there shared it.
    use host::analysis::classify::{class_of, classify};
    use host::analysis::fit::{SharedError, fit_with_shared};
    const GEOMETRIES: [(f64, f64); 26] = [
        (20.0, 0.0),
        (20.0, 20.0),
        (20.0, 45.0),
        (20.0, 58.0),
        (20.0, 70.0),
        (30.0, 0.0),
        (30.0, 15.0),
        (30.0, 30.0),
        (30.0, 50.0),
        (30.0, 70.0),
        (45.0, 0.0),
        (45.0, 23.0),
        (45.0, 44.0),
        (45.0, 44.5),
        (45.0, 45.0),
        (45.0, 58.0),
        (45.0, 70.0),
        (60.0, 0.0),
        (60.0, 0.5),
        (60.0, 1.0),
        (60.0, 1.5),
        (60.0, 2.0),
        (60.0, 30.0),
        (60.0, 45.0),
        (60.0, 60.0),
        (60.0, 70.0),
    ];
    let p = reference("G");
    let truth = move |ti: f64, tr: f64| {
        let (ci, cr) = (ti.to_radians().cos(), tr.to_radians().cos());
        let lommel_seeliger = 2.0 * 45f64.to_radians().cos() / (ci + cr);
        Sheet::ideal(p).radiance_factor(ti, tr) - p.rho_d + p.rho_d * lommel_seeliger
    };
    let truth_class = class_of(Some(p.sigma_deg), p.rho_s, p.rho_d);
    let run = common::run_seed();
    let (mut lost, mut right, mut covered, mut seen) = (0, 0, 0, Vec::new());
    for seed in 0..6u64 {
        let obs = readings_on(&GEOMETRIES, &truth, 100 * run + seed, (0.001, 0.0003), true);
        let mut shared = vec![SharedError {
            name: "tile certificate".into(),
            sensitivity: obs.iter().map(|o| 0.005 * o.radiance_factor).collect(),
            additive: Vec::new(),
        }];
        for theta_i in [20.0, 30.0, 45.0, 60.0] {
            shared.push(SharedError {
                name: format!("white θi={theta_i}°"),
                sensitivity: obs
                    .iter()
                    .map(|o| {
                        if o.theta_i_deg == theta_i {
                            -0.002 * o.radiance_factor
                        } else {
                            0.0
                        }
                    })
                    .collect(),
                additive: Vec::new(),
            });
        }
        // The readings above 5 on the detector's highest gain range, its ratio to the next
        // known to 0.33 %.
        shared.push(SharedError {
            name: "gain ranges 1/2".into(),
            sensitivity: obs
                .iter()
                .map(|o| {
                    if o.radiance_factor > 5.0 {
                        -0.0033 * o.radiance_factor
                    } else {
                        0.0
                    }
                })
                .collect(),
            additive: Vec::new(),
        });
        let without = FitOptions {
            extensions: false,
            ..FitOptions::default()
        };
        let paper_model = fit_with_shared(&obs, &shared, &without).expect("fit");
        lost += usize::from(paper_model.params.sigma_deg >= 60.0);
        let r = fit_with_shared(&obs, &shared, &on()).expect("fit");
        let c = classify(&r);
        right += usize::from(c.class == Some(truth_class));
        covered += usize::from(covers(r.ci95[SIGMA], p.sigma_deg));
        seen.push(format!(
            "seed {seed}: paper's model σ {:.2}; {} at {:.2}, σ {:.4} {:?}, {:?} {:?}",
            paper_model.params.sigma_deg,
            c.class_name(),
            c.confidence,
            r.params.sigma_deg,
            r.ci95[SIGMA],
            extended(&r),
            r.flags
        ));
    }
    // The case this tests: the paper's model alone loses the lobe (6 of 6 when written).
    assert!(lost >= 5, "lost in {lost} of 6: {seen:#?}");
    assert!(right >= 5 && covered >= 5, "{seen:#?}");
}

#[test]
fn a_member_as_good_as_the_best_that_does_not_pin_sigma_down_does_not_widen_it() {
    // Exact-TSL G on the 20 geometries an adaptive session had after its first batch (the
    // twelve sparse ones and eight about the specular peak at θi = 60° only), the noise
    // the session stated (0.26 % of the reading, 0.0016 at the floor). With the peak
    // seen at one θi, σ varying with θi may leave σ at 45° open (0.97 ± 3.6° in that
    // session); that member was within 2 of Akaike's best, and counted whole it made σ's
    // interval [0.001, 90]° (library and sheet refused the session as implausible). A
    // member counted now identifies σ (relative sd at most 0.5), so its interval is within
    // a factor e^0.98 of its estimate. What is asked, over 128 seeds: σ's interval holds σ
    // as a 95 % interval may (at most 13 misses) and stays below 6σ in every one (over 900
    // seeds of the code before, it reached 12–116σ; now at most 4.1σ), and within
    // [0.3σ, 3.5σ] in all but 16 (about 5.5 % are not, for the slope member's σ at 45° and
    // the shape sensitivity it brings, which are the readings' to settle: the adaptive
    // policy then crosses the peak at another θi; 15 % before). The slope member is among
    // the plausible in most seeds.
    const GEOMETRIES: [(f64, f64); 20] = [
        (60.0, 70.0),
        (60.0, 60.0),
        (45.0, 70.0),
        (30.0, 70.0),
        (20.0, 70.0),
        (45.0, 45.0),
        (30.0, 30.0),
        (20.0, 20.0),
        (20.0, 0.0),
        (30.0, 0.0),
        (45.0, 0.0),
        (60.0, 0.0),
        (60.0, 56.0),
        (60.0, 58.0),
        (60.0, 59.0),
        (60.0, 59.5),
        (60.0, 60.5),
        (60.0, 61.0),
        (60.0, 62.0),
        (60.0, 64.0),
    ];
    const SEEDS: u64 = 128;
    let p = reference("G");
    let truth = tsl(p);
    let run = common::run_seed();
    let (mut exercised, mut wide, mut widest) = (0, 0, 0.0_f64);
    let mut missed = Vec::new();
    for seed in 0..SEEDS {
        let obs = readings_on(
            &GEOMETRIES,
            &truth,
            1000 * run + seed,
            (0.0026, 0.0016),
            true,
        );
        let r = fit(&obs, &on()).expect("fit");
        let (lo, hi) = r.ci95[SIGMA].expect("σ's interval");
        let plausible = r.extension.as_ref().map_or(&[][..], |e| &e.plausible[..]);
        exercised += usize::from(plausible.iter().any(|m| m == "TSL + σ varying with θi"));
        wide += usize::from(lo < 0.3 * p.sigma_deg || hi > 3.5 * p.sigma_deg);
        widest = widest.max(hi / p.sigma_deg);
        let said = format!(
            "seed {seed}: σ {} [{lo}, {hi}] against {} (plausible: {plausible:?})",
            r.params.sigma_deg, p.sigma_deg
        );
        assert!(hi < 6.0 * p.sigma_deg, "{said}");
        if !covers(Some((lo, hi)), p.sigma_deg) {
            missed.push(said);
        }
    }
    // A 95 % interval may miss: run seed 15135's draw 23 missed 0.8° by 0.0001° (upper
    // end 0.79988°), the one miss of that run. Over 128 draws more than 13 misses has
    // probability 0.5 % at the nominal 95 % (binomial).
    assert!(
        missed.len() <= 13,
        "{} of {SEEDS} missed: {missed:#?}",
        missed.len()
    );
    println!(
        "of {SEEDS} seeds: outside [0.3σ, 3.5σ] {wide}, the highest upper end {widest:.2}σ, the slope member plausible in {exercised}"
    );
    assert!(
        wide <= 16,
        "{wide} of {SEEDS} intervals outside [0.3σ, 3.5σ]"
    );
    assert!(
        exercised >= SEEDS as usize / 2,
        "the case was exercised in {exercised} seeds"
    );
}
