//! The accuracy campaign in small (`gonio accuracy` runs it at full size, docs/ACCURACY.md):
//! whole simulated sessions on the realistic instrument and on sheets that are not the
//! model, judged against the truth the simulator was given.
use host::analysis::model::{self, SIGMA};
use host::instrument::sim::{SimOptions, sample_params};
use host::session::{Outcome, Policy};
use host::study::accuracy::{self, Case, Part, Row, Tally};
use host::study::{SimulatedRun, simulated_session};

fn threads() -> usize {
    std::thread::available_parallelism().map_or(2, |n| n.get())
}

/// The campaign's sessions of `part`, `n` per case and policy.
fn campaign(part: Part, n: usize) -> (Vec<Case>, Vec<Row>) {
    let cases = accuracy::cases();
    let specs: Vec<_> = accuracy::plan(&cases, n, n)
        .into_iter()
        .filter(|s| cases[s.case].part == part)
        .collect();
    let rows = accuracy::run_all(&cases, &specs, threads(), &|| {});
    assert_eq!(rows.len(), specs.len(), "every session ran");
    (cases, rows)
}

/// With the effects the budget and the model account for switched on (`--physics real`:
/// range-gain errors, tile error, lamp drift, a drawn arm zero error, the detector window),
/// and on the ideal instrument, the 95 % intervals cover the truth. 12 sessions per paper,
/// physics and policy: 96 per physics. Before the arm zero entered the budget, J1's σ was
/// covered in 24–34 % of real sessions and the real pool's σ in about 75 %.
#[test]
fn the_intervals_cover_the_truth_on_the_real_and_the_ideal_instrument() {
    let (cases, rows) = campaign(Part::Coverage, 12);
    let tallies = accuracy::tallies(&cases, &rows);
    for physics in [
        host::instrument::sim::Physics::Ideal,
        host::instrument::sim::Physics::Real,
    ] {
        let of: Vec<&Tally> = tallies
            .iter()
            .filter(|(c, _, _)| cases[*c].physics == physics)
            .map(|(_, _, t)| t)
            .collect();
        let n: usize = of.iter().map(|t| t.sessions).sum();
        assert_eq!(
            of.iter().map(|t| t.failed).sum::<usize>(),
            0,
            "{physics:?}: every session finishes"
        );
        for (k, what) in ["σ", "ρs", "ρd"].iter().enumerate() {
            let covered: usize = of.iter().map(|t| t.covered[k]).sum();
            let share = covered as f64 / n as f64;
            println!(
                "{physics:?}: {what} covered {covered}/{n} ({:.1} %)",
                100.0 * share
            );
            // 96 sessions at a true 95 %: below 85 % with probability < 0.1 %.
            assert!(
                (0.85..=1.0).contains(&share),
                "{physics:?} {what}: {covered}/{n}"
            );
        }
        for t in &of {
            assert!(
                t.class_right == t.sessions,
                "the class is right on scenes the model describes: {t:?}"
            );
        }
    }
    // On ideal scenes lack-of-fit is a false alarm, at most 2 % (here ≤ 4 of 96: a binomial
    // at 2 % exceeds that in 5 % of campaigns).
    let ideal: Vec<&Tally> = tallies
        .iter()
        .filter(|(c, _, _)| cases[*c].physics == host::instrument::sim::Physics::Ideal)
        .map(|(_, _, t)| t)
        .collect();
    let flags: usize = ideal.iter().map(|t| t.lack_of_fit).sum();
    println!("lack-of-fit on ideal scenes: {flags}/96");
    assert!(
        flags <= 4,
        "{flags} false lack-of-fit flags in 96 ideal sessions"
    );
}

/// Sheets the model does not describe (GGX and Cauchy lobes of G and SG, a specular bump on
/// J1 and J2, a forward lobe on PPC and J3) and an arm 0.3° off on every paper: never a
/// wrong class with confidence ≥ 0.95 and no `lack-of-fit` flag. The non-Gaussian lobes and
/// the bump are flagged every time (or, where the fit tests the extensions, flagged or
/// `model-extended`). Before, a G sheet with a heavy-tailed lobe was "SG, confidence 1.00"
/// with no flag.
#[test]
fn sheets_that_are_not_the_model_are_never_confidently_wrong() {
    let (cases, rows) = campaign(Part::Robustness, 5);
    for (c, policy, t) in accuracy::tallies(&cases, &rows) {
        let case = &cases[c];
        println!(
            "{} {}: class right {}/{}, lack-of-fit {}, lack-of-fit or model-extended {}, undecided {}, wrong but said {}, confidently wrong {}",
            case.name(),
            accuracy::policy_name(policy),
            t.class_right,
            t.sessions,
            t.lack_of_fit,
            t.not_the_model,
            t.undecided,
            t.wrong_but_said,
            t.confidently_wrong
        );
        assert_eq!(t.failed, 0, "{}: every session finishes", case.name());
        assert_eq!(
            t.confidently_wrong,
            0,
            "{} {}: confidently wrong",
            case.name(),
            accuracy::policy_name(policy)
        );
        if matches!(
            case.effect,
            accuracy::Effect::Lobe(_) | accuracy::Effect::SpecularBump
        ) {
            // Said by the flag, or by the term the fit added for it where the fit tests
            // the extensions (a heavy tail is one of them; GGX is then G at 5 of 5,
            // extended, none flagged).
            assert_eq!(
                t.not_the_model,
                t.sessions,
                "{}: the sheet is not the model and the result says so",
                case.name()
            );
        }
        if matches!(case.effect, accuracy::Effect::ArmOffset(_)) {
            // An offset the fit models (fitted, or in the budget) costs nothing of the class.
            assert_eq!(t.class_right, t.sessions, "{}", case.name());
        }
    }
}

/// An adaptive session on the simulated instrument, its fit testing the model's extensions
/// or not.
fn session_fitting(sample: &str, options: &SimOptions, extensions: bool) -> Outcome {
    let run = SimulatedRun {
        sample,
        options,
        policy: Policy::from(host::session::PolicyChoice::Adaptive),
        integration_ms: None,
    };
    simulated_session(&run, |session| session.with_model_extensions(extensions))
        .expect("a session")
        .0
}

/// A table of one of the papers, replayed with `--scene-file`, gives the built-in scene's
/// class and a σ within its interval, fitted with the paper's model: the replay is what
/// is tested, and that fit is continuous in the readings. With the extensions the class is
/// the same and the two intervals overlap; σ may move by a fraction of its interval where a
/// term's test falls on one side of its critical value for one and the other for the other
/// (the J1 table of seed 11: 16.7465 replayed against the built-in's [16.4403, 16.7359]).
#[test]
fn a_replayed_table_gives_the_built_in_scenes_class_and_sigma() {
    let dir = std::env::temp_dir().join(format!("gonio-accuracy-replay-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    for sample in ["SG", "PPC", "J1"] {
        let params = sample_params(sample).unwrap();
        // A quarter-degree grid: finer than the detector's 1° window, as a measured table
        // of a glossy paper would need to be.
        let mut text = String::from("theta_i,theta_r,radiance_factor\n");
        for theta_i in [20, 30, 45, 60] {
            for step in 0..=280 {
                let theta_r = f64::from(step) * 0.25;
                text.push_str(&format!(
                    "{theta_i},{theta_r},{}\n",
                    model::radiance_factor(&params, f64::from(theta_i), theta_r)
                ));
            }
        }
        let path = dir.join(format!("{sample}.csv"));
        std::fs::write(&path, text).unwrap();
        for seed in [11, 12, 13] {
            let options = SimOptions {
                seed,
                ..SimOptions::default()
            };
            let replay = SimOptions {
                seed,
                scene_file: Some(path.clone()),
                ..SimOptions::default()
            };
            for extensions in [false, true] {
                let built_in = session_fitting(sample, &options, extensions);
                let replayed = session_fitting("replay", &replay, extensions);
                let (a, b) = (&built_in.report, &replayed.report);
                let case = format!("{sample} seed {seed}, extensions {extensions}");
                assert_eq!(
                    a.classification.class, b.classification.class,
                    "{case}: the replay's class"
                );
                let (sa, sb) = (a.fit.sigma_deg().unwrap(), b.fit.sigma_deg().unwrap());
                let (lo, hi) = a.fit.ci95[SIGMA].unwrap();
                let (rlo, rhi) = b.fit.ci95[SIGMA].unwrap();
                println!(
                    "{case}: σ built-in {sa:.4} [{lo:.4}, {hi:.4}], replayed {sb:.4} [{rlo:.4}, {rhi:.4}]"
                );
                if extensions {
                    assert!(
                        rlo <= hi && lo <= rhi,
                        "{case}: the replay's σ interval [{rlo}, {rhi}] and the built-in's [{lo}, {hi}] are apart"
                    );
                } else {
                    assert!(
                        (lo..=hi).contains(&sb),
                        "{case}: replayed σ {sb} outside the built-in's [{lo}, {hi}]"
                    );
                }
            }
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// Sweep sessions on ideal scenes (10 per paper, G, SG, PPC, J1): `lack-of-fit` is a false
/// alarm there, raised no more often than its stated rate allows, and the χ² test's p-value
/// is not piled up near 0. The bins' noise is scaled to their own scatter, an estimate
/// with 8.5 % spread in the first pass's 1,400 bins (6 % in the full plane's 2,800); before the χ² test allowed for that,
/// p < 0.005 in about one session in six and the flag in 14 of 80 (docs/TRADE.md).
#[test]
fn sweep_sessions_on_ideal_scenes_raise_lack_of_fit_at_its_stated_rate() {
    use host::instrument::sim::Physics;
    use host::session::PolicyChoice;
    let cases = accuracy::cases();
    let specs: Vec<_> = accuracy::plan_policies(&cases, 10, 0, &[PolicyChoice::Sweep])
        .into_iter()
        .filter(|s| cases[s.case].part == Part::Coverage && cases[s.case].physics == Physics::Ideal)
        .collect();
    assert_eq!(specs.len(), 40);
    let rows = accuracy::run_all(&cases, &specs, threads(), &|| {});
    assert_eq!(rows.len(), specs.len(), "every session ran");
    let p_values: Vec<f64> = rows.iter().filter_map(|r| r.gof_p).collect();
    assert_eq!(
        p_values.len(),
        rows.len(),
        "every sweep fit is weighted and has a χ² test"
    );
    let low = p_values.iter().filter(|&&p| p < 0.05).count();
    let flags = rows.iter().filter(|r| r.lack_of_fit()).count();
    println!("sweeps on ideal scenes: χ² p < 0.05 in {low} of 40, lack-of-fit in {flags}");
    // p < 0.05 in 2 of 40 expected; 9 or more has probability < 0.1 % under the model.
    assert!(low <= 8, "χ² p-values pile up near 0: {p_values:?}");
    assert!(
        flags <= host::study::reliability::lack_of_fit_allowed(rows.len()),
        "lack-of-fit in {flags} of 40 ideal sweep sessions"
    );
}

/// The simulator without noise (`--noise-scale 0`, documented as noiseless): every policy's
/// session finishes with the paper's class and σ within 0.5 % of the truth. Its readings are
/// known to the ADC's resolution; before, their uncertainty was 0 and every such session
/// stopped with "the fit failed".
#[test]
fn a_noiseless_instrument_gives_finished_sessions_and_the_truth() {
    use host::session::PolicyChoice;
    for (sample, class, policy) in [
        ("PPC", "rough-II", PolicyChoice::Adaptive),
        ("G", "G", PolicyChoice::Paper),
        ("SG", "SG", PolicyChoice::Sweep),
    ] {
        let options = SimOptions {
            seed: 4,
            noise_scale: 0.0,
            ..SimOptions::default()
        };
        let run = SimulatedRun {
            sample,
            options: &options,
            policy: Policy::from(policy),
            integration_ms: None,
        };
        let (outcome, _) = simulated_session(&run, |session| session)
            .unwrap_or_else(|e| panic!("{sample} {policy:?}: {e}"));
        let truth = sample_params(sample).unwrap().sigma_deg;
        let sigma = outcome.report.fit.sigma_deg().expect("σ resolved");
        println!(
            "{sample} {policy:?} noiseless: σ {sigma:.5} (truth {truth}), class {}",
            outcome.report.classification.class_name()
        );
        assert_eq!(
            outcome.report.classification.class_name(),
            class,
            "{sample} {policy:?}"
        );
        assert!(
            (sigma / truth - 1.0).abs() < 0.005,
            "{sample} {policy:?}: σ {sigma} against {truth}"
        );
    }
}

/// A sweep session's first pass covers two incidences (θi = 20°, 60°); a fit that lacks
/// fit there, or whose model the data extended, gets the rest of the full plane before it
/// is reported, so the flag or the term rests on every incidence of Strategy 1. Sheets the
/// model does not describe (G with a Cauchy lobe, J1 with its specular bump at 0.3), seeds
/// drawn for this run; an ideal G sheet that needs no refinement stops after the first
/// pass's two lines.
#[test]
fn a_sweep_session_that_lacks_fit_measures_the_whole_plane() {
    use host::instrument::sim::LobeChoice;
    use host::session::PolicyChoice;
    let drawn = crate::common::run_seed();
    let incidences = |outcome: &Outcome| {
        let mut seen: Vec<f64> = Vec::new();
        for p in outcome
            .points
            .iter()
            .filter(|p| p.theta_r_span_deg > 0.0 && p.radiance_factor.is_some())
        {
            if !seen.contains(&p.theta_i_deg) {
                seen.push(p.theta_i_deg);
            }
        }
        seen.sort_by(f64::total_cmp);
        seen
    };
    let whole = |outcome: &Outcome, theta_i: f64| {
        let bins: Vec<f64> = outcome
            .points
            .iter()
            .filter(|p| p.theta_i_deg == theta_i && p.theta_r_span_deg > 0.0)
            .map(|p| p.theta_r_deg)
            .collect();
        bins.iter().any(|&r| r < 0.5) && bins.iter().any(|&r| r > 69.5)
    };
    for k in 0..2 {
        let seed = drawn + k;
        let cases = [
            (
                "G",
                SimOptions {
                    seed,
                    lobe: LobeChoice::Cauchy,
                    ..SimOptions::default()
                },
                true,
            ),
            (
                "J1",
                SimOptions {
                    seed,
                    specular_bump: 0.3,
                    ..SimOptions::default()
                },
                true,
            ),
            (
                "G",
                SimOptions {
                    seed,
                    ..SimOptions::default()
                },
                false,
            ),
        ];
        for (sample, options, departs) in cases {
            let run = SimulatedRun {
                sample,
                options: &options,
                policy: Policy::from(PolicyChoice::Sweep),
                integration_ms: None,
            };
            let (outcome, _) = simulated_session(&run, |session| session)
                .unwrap_or_else(|e| panic!("{sample} seed {seed}: {e}"));
            let seen = incidences(&outcome);
            use host::analysis::flags::Flag;
            // Flagged, or a term added for what the model lacks where the fit tests the
            // extensions (the Cauchy G is then extended by a heavy tail, not flagged): either
            // way the whole plane is read before the result is reported.
            let flagged = outcome.flags.contains(&Flag::LackOfFit)
                || outcome.flags.contains(&Flag::ModelExtended);
            println!(
                "{sample} seed {seed} ({}): incidences {seen:?}, flagged or extended {flagged}, class {} at {:.2}",
                if departs {
                    "not the model"
                } else {
                    "the model"
                },
                outcome.report.classification.class_name(),
                outcome.report.classification.confidence
            );
            if departs {
                assert!(
                    flagged,
                    "{sample} seed {seed}: a sheet the model does not describe is flagged or extended"
                );
                assert_eq!(
                    seen,
                    [20.0, 30.0, 45.0, 60.0],
                    "{sample} seed {seed}: the whole plane"
                );
                for theta_i in seen {
                    assert!(
                        whole(&outcome, theta_i),
                        "{sample} seed {seed}: θr 0–70° at θi = {theta_i}°"
                    );
                }
            } else if outcome.refinements.is_empty() {
                // The first pass was enough (the usual case): its two lines only, in the
                // issue's 8 s with the gain calibration apart.
                assert_eq!(
                    seen,
                    [20.0, 60.0],
                    "{sample} seed {seed}: the first pass only"
                );
                let gains: f64 = outcome
                    .calibration
                    .gain_ratios
                    .iter()
                    .map(|g| g.device_seconds)
                    .sum();
                assert!(
                    outcome.device_seconds - gains < 8.0,
                    "{sample} seed {seed}: {} s less {gains} s",
                    outcome.device_seconds
                );
            }
        }
    }
}

/// A sweep's bins are recorded where the detector arm stood on average while they were
/// read (the dwell model), so on a sheet that is the model each reads the model there and
/// over its interval: on the simulator at a hundredth of the reference noise, every
/// usable bin within 0.6 of the reference instrument's noise sd of the truth, on G (σ
/// 0.8°, the narrowest lobe), SG and J1, seeds drawn for this run. With bins at their
/// intervals' middles, the first bin of a sweep (from rest) was 2.6 noise sd off on SG's
/// 60° flank and the ramps' bins a third. What is left is on G's steep flanks (up to about
/// 0.5 sd, alternating in sign from bin to bin): the arm's dwell spreads over a bin's
/// microsteps unevenly, and the fit takes the bin as a uniform window over its interval.
#[test]
fn a_sweep_s_bins_read_the_scene_where_they_are_recorded() {
    use host::session::PolicyChoice;
    let drawn = crate::common::run_seed();
    let noise_scale = 0.01;
    for (k, sample) in ["G", "SG", "J1"].into_iter().enumerate() {
        let seed = drawn + k as u64;
        let options = SimOptions {
            seed,
            noise_scale,
            ..SimOptions::default()
        };
        let run = SimulatedRun {
            sample,
            options: &options,
            policy: Policy::from(PolicyChoice::Sweep),
            integration_ms: None,
        };
        let (outcome, _) = simulated_session(&run, |session| session)
            .unwrap_or_else(|e| panic!("{sample} seed {seed}: {e}"));
        let truth = sample_params(sample).unwrap();
        let acceptance = Some(model::DEFAULT_ACCEPTANCE_DEG);
        let mut worst = (0.0_f64, 0.0, 0.0);
        let mut bins = 0;
        for p in outcome
            .points
            .iter()
            .filter(|p| p.theta_r_span_deg > 0.0 && !p.superseded && p.unusable.is_none())
        {
            let (Some(r), Some(std)) = (p.radiance_factor, p.std) else {
                continue;
            };
            let (m, _) = model::evaluate_reading(
                &truth,
                p.theta_i_deg,
                p.theta_r_deg,
                p.theta_r_span_deg,
                acceptance,
            );
            let z = (r - m) / (std / noise_scale);
            bins += 1;
            if z.abs() > worst.0.abs() {
                worst = (z, p.theta_i_deg, p.theta_r_deg);
            }
        }
        println!(
            "{sample} seed {seed}: {bins} bins, the worst {:.3} reference sd off at ({}°, {:.3}°)",
            worst.0, worst.1, worst.2
        );
        assert!(bins >= 1_300, "{sample} seed {seed}: {bins} bins");
        assert!(
            worst.0.abs() < 0.6,
            "{sample} seed {seed}: a bin {:.3} reference sd off the truth at ({}°, {:.3}°)",
            worst.0,
            worst.1,
            worst.2
        );
    }
}
