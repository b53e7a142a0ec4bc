//! The accuracy campaign in small (`gonio accuracy` runs it at full size, docs/ACCURACY.md):
//! whole simulated sessions on the realistic instrument and on sheets that are not the
//! model, judged against the truth the simulator was given.
use host::analysis::model::{self, SIGMA};
use host::instrument::sim::{SimOptions, sample_params};
use host::session::{Outcome, Policy};
use host::study::{SimulatedRun, simulated_session};
use host::study::accuracy::{self, Case, Part, Row, Tally};

fn threads() -> usize {
    std::thread::available_parallelism().map_or(2, |n| n.get())
}

/// The campaign's sessions of `part`, `n` per case and policy.
fn campaign(part: Part, n: usize) -> (Vec<Case>, Vec<Row>) {
    let cases = accuracy::cases();
    let specs: Vec<_> = accuracy::plan(&cases, n, n).into_iter().filter(|s| cases[s.case].part == part).collect();
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
    for physics in [host::instrument::sim::Physics::Ideal, host::instrument::sim::Physics::Real] {
        let of: Vec<&Tally> = tallies.iter().filter(|(c, _, _)| cases[*c].physics == physics).map(|(_, _, t)| t).collect();
        let n: usize = of.iter().map(|t| t.sessions).sum();
        assert_eq!(of.iter().map(|t| t.failed).sum::<usize>(), 0, "{physics:?}: every session finishes");
        for (k, what) in ["σ", "ρs", "ρd"].iter().enumerate() {
            let covered: usize = of.iter().map(|t| t.covered[k]).sum();
            let share = covered as f64 / n as f64;
            println!("{physics:?}: {what} covered {covered}/{n} ({:.1} %)", 100.0 * share);
            // 96 sessions at a true 95 %: below 85 % with probability < 0.1 %.
            assert!((0.85..=1.0).contains(&share), "{physics:?} {what}: {covered}/{n}");
        }
        for t in &of {
            assert!(t.class_right == t.sessions, "the class is right on scenes the model describes: {t:?}");
        }
    }
    // On ideal scenes lack-of-fit is a false alarm, at most 2 % (here ≤ 4 of 96: a binomial
    // at 2 % exceeds that in 5 % of campaigns).
    let ideal: Vec<&Tally> = tallies.iter().filter(|(c, _, _)| cases[*c].physics == host::instrument::sim::Physics::Ideal).map(|(_, _, t)| t).collect();
    let flags: usize = ideal.iter().map(|t| t.lack_of_fit).sum();
    println!("lack-of-fit on ideal scenes: {flags}/96");
    assert!(flags <= 4, "{flags} false lack-of-fit flags in 96 ideal sessions");
}

/// Sheets the model does not describe (GGX and Cauchy lobes of G and SG, a specular bump on
/// J1 and J2, a forward lobe on PPC and J3) and an arm 0.3° off on every paper: never a
/// wrong class with confidence ≥ 0.95 and no `lack-of-fit` flag. The non-Gaussian lobes and
/// the bump are flagged every time. Before, a G sheet with a heavy-tailed lobe was "SG,
/// confidence 1.00" with no flag.
#[test]
fn sheets_that_are_not_the_model_are_never_confidently_wrong() {
    let (cases, rows) = campaign(Part::Robustness, 5);
    for (c, policy, t) in accuracy::tallies(&cases, &rows) {
        let case = &cases[c];
        println!(
            "{} {}: class right {}/{}, lack-of-fit {}, undecided {}, wrong but said {}, confidently wrong {}",
            case.name(),
            accuracy::policy_name(policy),
            t.class_right,
            t.sessions,
            t.lack_of_fit,
            t.undecided,
            t.wrong_but_said,
            t.confidently_wrong
        );
        assert_eq!(t.failed, 0, "{}: every session finishes", case.name());
        assert_eq!(t.confidently_wrong, 0, "{} {}: confidently wrong", case.name(), accuracy::policy_name(policy));
        if matches!(case.effect, accuracy::Effect::Lobe(_) | accuracy::Effect::SpecularBump) {
            assert_eq!(t.lack_of_fit, t.sessions, "{}: the sheet is not the model and the result says so", case.name());
        }
        if matches!(case.effect, accuracy::Effect::ArmOffset(_)) {
            // An offset the fit models (fitted, or in the budget) costs nothing of the class.
            assert_eq!(t.class_right, t.sessions, "{}", case.name());
        }
    }
}

fn session(sample: &str, options: &SimOptions) -> Outcome {
    let run = SimulatedRun { sample, options, policy: Policy::from(host::session::PolicyChoice::Adaptive), integration_ms: None };
    simulated_session(&run, |session| session).expect("a session").0
}

/// A table of one of the papers, replayed with `--scene-file`, gives the built-in scene's
/// class and a σ within its interval.
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
                text.push_str(&format!("{theta_i},{theta_r},{}\n", model::radiance_factor(&params, f64::from(theta_i), theta_r)));
            }
        }
        let path = dir.join(format!("{sample}.csv"));
        std::fs::write(&path, text).unwrap();
        for seed in [11, 12, 13] {
            let built_in = session(sample, &SimOptions { seed, ..SimOptions::default() });
            let replayed = session("replay", &SimOptions { seed, scene_file: Some(path.clone()), ..SimOptions::default() });
            let (a, b) = (&built_in.report, &replayed.report);
            assert_eq!(a.classification.class, b.classification.class, "{sample} seed {seed}: the replay's class");
            let (sa, sb) = (a.fit.sigma_deg().unwrap(), b.fit.sigma_deg().unwrap());
            let (lo, hi) = a.fit.ci95[SIGMA].unwrap();
            println!("{sample} seed {seed}: σ built-in {sa:.4} [{lo:.4}, {hi:.4}], replayed {sb:.4}");
            assert!((lo..=hi).contains(&sb), "{sample} seed {seed}: replayed σ {sb} outside the built-in's [{lo}, {hi}]");
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// Sweep sessions on ideal scenes (10 per paper, G, SG, PPC, J1): `lack-of-fit` is a false
/// alarm there, raised no more often than its stated rate allows, and the χ² test's p-value
/// is not piled up near 0. The bins' noise is scaled to their own scatter, an estimate
/// with 6 % spread in a pass's 2,800 bins; before the χ² test allowed for that,
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
    assert_eq!(p_values.len(), rows.len(), "every sweep fit is weighted and has a χ² test");
    let low = p_values.iter().filter(|&&p| p < 0.05).count();
    let flags = rows.iter().filter(|r| r.lack_of_fit()).count();
    println!("sweeps on ideal scenes: χ² p < 0.05 in {low} of 40, lack-of-fit in {flags}");
    // p < 0.05 in 2 of 40 expected; 9 or more has probability < 0.1 % under the model.
    assert!(low <= 8, "χ² p-values pile up near 0: {p_values:?}");
    assert!(flags <= host::study::reliability::lack_of_fit_allowed(rows.len()), "lack-of-fit in {flags} of 40 ideal sweep sessions");
}

/// The simulator without noise (`--noise-scale 0`, documented as noiseless): every policy's
/// session finishes with the paper's class and σ within 0.5 % of the truth. Its readings are
/// known to the ADC's resolution; before, their uncertainty was 0 and every such session
/// stopped with "the fit failed".
#[test]
fn a_noiseless_instrument_gives_finished_sessions_and_the_truth() {
    use host::session::PolicyChoice;
    for (sample, class, policy) in [("PPC", "rough-II", PolicyChoice::Adaptive), ("G", "G", PolicyChoice::Paper), ("SG", "SG", PolicyChoice::Sweep)] {
        let options = SimOptions { seed: 4, noise_scale: 0.0, ..SimOptions::default() };
        let run = SimulatedRun { sample, options: &options, policy: Policy::from(policy), integration_ms: None };
        let (outcome, _) = simulated_session(&run, |session| session).unwrap_or_else(|e| panic!("{sample} {policy:?}: {e}"));
        let truth = sample_params(sample).unwrap().sigma_deg;
        let sigma = outcome.report.fit.sigma_deg().expect("σ resolved");
        println!("{sample} {policy:?} noiseless: σ {sigma:.5} (truth {truth}), class {}", outcome.report.classification.class_name());
        assert_eq!(outcome.report.classification.class_name(), class, "{sample} {policy:?}");
        assert!((sigma / truth - 1.0).abs() < 0.005, "{sample} {policy:?}: σ {sigma} against {truth}");
    }
}
