//! The speed–accuracy study and the adaptive policy's targets, on whole simulated sessions.

use host::study::trade::{self, RunSpec};
use std::process::Command;

/// The targets over 20 seeds per paper at 100 ms: glossy papers reach σ within 5 %
/// in ≥ 95 % of sessions in at most half the paper's device time; rough papers stop after
/// Strategy 1 in ≥ 95 % with the right class; no paper loses class accuracy.
#[test]
fn the_adaptive_policy_meets_its_targets_over_twenty_seeds() {
    let runs: Vec<RunSpec> = trade::plan_runs(20, true)
        .into_iter()
        .filter(|r| {
            (r.policy == "paper" || r.policy == "adaptive")
                && r.integration_ms == trade::TARGET_INTEGRATION_MS
        })
        .collect();
    assert_eq!(runs.len(), 8 * 20 * 2);
    let rows = trade::run_all(&runs, 2, &|| {}).expect("every session completes");
    let checks = trade::check_targets(&rows);
    assert_eq!(checks.len(), 8);
    for check in &checks {
        assert_eq!(check.sessions, 20);
        assert!(check.met, "{}: {}", check.sample, check.what);
        assert!(
            check.adaptive.class_accuracy >= check.paper.class_accuracy,
            "{}",
            check.sample
        );
    }
    // Every session ends above the paper's σ_l criterion, adaptive included.
    assert!(
        rows.iter().all(|r| r.sigma_ok),
        "a session stopped with σ ≤ σ_l"
    );
}

#[test]
fn the_study_covers_every_schedule_policy_and_integration_time() {
    let runs = trade::plan_runs(2, false);
    // 8 Strategy 1 M + 10 Strategy 2 δ + paper + adaptive, 3 integration times, 8 papers,
    // 2 seeds; and the 5 sweep settings and the mixed policy at one integration time (a
    // sweep's bins are blocks).
    assert_eq!(
        runs.len(),
        20 * 3 * 8 * 2 + (trade::SWEEP_SETTINGS.len() + 1) * 8 * 2
    );
    for policy in trade::POLICIES {
        assert!(runs.iter().any(|r| r.policy == policy));
    }
    for ms in trade::INTEGRATION_MS {
        assert!(
            runs.iter()
                .any(|r| r.integration_ms == ms && r.policy == "strategy2")
        );
    }
    let quick = trade::plan_runs(2, true);
    assert!(
        quick
            .iter()
            .all(|r| r.integration_ms == trade::TARGET_INTEGRATION_MS
                || r.policy == "paper"
                || r.policy == "adaptive")
    );
}

/// The mixed policy (the adaptive policy with sweeps across the peak as candidates next to
/// its point batches) against the adaptive policy, the same sessions (seeds drawn for
/// this run, 4 per paper): on G, whose σ Strategy 1 does not resolve, a slow sweep across
/// the specular direction replaces the probe's points; on SG the σ_l check's spacing is
/// settled by one sweep across the peak (on at least three of each one's four sessions: a
/// false lack-of-fit after Strategy 1 may settle σ first); every class right, G's and SG's
/// σ within 5 %, G in less device time on average; a session that takes no sweep (every
/// rough paper's: they need nothing after Strategy 1) measured exactly as the adaptive
/// policy measures it.
#[test]
fn the_mixed_policy_sweeps_where_a_sweep_brings_more_per_second() {
    let first = crate::common::run_seed();
    let runs: Vec<RunSpec> = ["mixed", "adaptive"]
        .into_iter()
        .flat_map(|policy| {
            ["G", "SG", "PPC", "J1"]
                .into_iter()
                .map(move |sample| (policy, sample))
        })
        .flat_map(|(policy, sample)| {
            (first..first + 4).map(move |seed| RunSpec {
                policy,
                setting: String::new(),
                sample,
                seed,
                integration_ms: trade::TARGET_INTEGRATION_MS,
                physics: Default::default(),
            })
        })
        .collect();
    let rows = trade::run_all(&runs, 2, &|| {}).expect("every session completes");
    for sample in ["G", "SG", "PPC", "J1"] {
        let of = |policy: &str| {
            rows.iter()
                .filter(|r| r.spec.policy == policy && r.spec.sample == sample)
                .collect::<Vec<_>>()
        };
        let (mixed, adaptive) = (of("mixed"), of("adaptive"));
        assert_eq!(mixed.len(), 4);
        let mean = |rows: &[&trade::Row]| {
            rows.iter().map(|r| r.device_seconds).sum::<f64>() / rows.len() as f64
        };
        println!(
            "{sample} seeds {first}–{}: mixed {:.1} s, adaptive {:.1} s",
            first + 3,
            mean(&mixed),
            mean(&adaptive)
        );
        let glossy = sample == "G" || sample == "SG";
        let mut swept = 0;
        for r in &mixed {
            assert!(
                r.class_correct && r.sigma_ok,
                "{sample} seed {}: {r:?}",
                r.spec.seed
            );
            if glossy {
                assert!(
                    r.sigma_rel_err.abs() <= 0.05,
                    "{sample} seed {}: σ off by {:.2} %",
                    r.spec.seed,
                    100.0 * r.sigma_rel_err
                );
            }
            // Bins are readings with a span: more than any batch of points would add.
            if glossy && r.geometries > 30 {
                swept += 1;
            } else {
                // The two policies differ only where the mixed one takes a sweep: a session
                // without one (a rough paper; a glossy one whose Strategy 1 raised a false
                // lack-of-fit, whose batch over the whole θr range then settled σ, as SG's
                // on seed 38884 did) is the adaptive session reading for reading.
                let same = adaptive
                    .iter()
                    .find(|a| a.spec.seed == r.spec.seed)
                    .expect("every seed under both policies");
                assert_eq!(
                    (r.geometries, r.device_seconds),
                    (same.geometries, same.device_seconds),
                    "{sample} seed {}: no sweep, yet not the adaptive session",
                    r.spec.seed
                );
            }
        }
        // The sweep is the mixed policy's point on glossy papers: taken on every session
        // but one whose Strategy 1 raises a false lack-of-fit that its batches then settle
        // (`gonio trade --seeds 100 --policies mixed`: SG seed 55, 1 of 100; G none), so on
        // at least three of the four (two without, at 1 %: 6 runs in 10,000).
        if glossy {
            assert!(
                swept >= 3,
                "{sample} seeds {first}–{}: {swept} of 4 sessions swept",
                first + 3
            );
        }
        // G's probe is where sweeps save time (docs/TRADE.md: 15.1 s against 17.4 s over
        // 100 sessions); SG's σ_l sweep saves little on average (16.8 s against 17.0 s), and
        // one session in twenty or so spends more on a lack-of-fit batch. Four seeds cannot
        // show the 100 sessions' 2.3 s (the mean of four paired differences was above 0 for
        // seeds 6726–6729): what they must not show is mixed significantly slower — the
        // paired differences' mean beyond three standard errors above 0.
        if sample == "G" {
            let differences: Vec<f64> = mixed
                .iter()
                .filter_map(|m| {
                    let a = adaptive.iter().find(|a| a.spec.seed == m.spec.seed)?;
                    Some(m.device_seconds - a.device_seconds)
                })
                .collect();
            assert_eq!(differences.len(), 4, "every seed under both policies");
            let n = differences.len() as f64;
            let d = differences.iter().sum::<f64>() / n;
            let sd = (differences.iter().map(|x| (x - d).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
            assert!(
                d < 3.0 * sd / n.sqrt(),
                "{sample} seeds {first}–{}: mixed {:.2} s against adaptive {:.2} s (paired mean {d:+.2} s, sd {sd:.2} s)",
                first + 3,
                mean(&mixed),
                mean(&adaptive)
            );
        }
    }
}

#[test]
fn more_integration_time_buys_a_smaller_sigma_error_under_a_fixed_schedule() {
    // Strategy 2 at δ = 2° on SG: σ is resolved at every integration time, and its error
    // shrinks as the noise falls with 1/√T.
    let runs: Vec<RunSpec> = [25, 400]
        .iter()
        .flat_map(|&ms| {
            (1..=8).map(move |seed| RunSpec {
                policy: "strategy2",
                setting: "2".into(),
                sample: "SG",
                seed,
                integration_ms: ms,
                physics: Default::default(),
            })
        })
        .collect();
    let rows = trade::run_all(&runs, 2, &|| {}).unwrap();
    let (fast, slow): (Vec<_>, Vec<_>) = rows.iter().partition(|r| r.spec.integration_ms == 25);
    let rms = |rows: &[&trade::Row]| {
        (rows.iter().map(|r| r.sigma_rel_err.powi(2)).sum::<f64>() / rows.len() as f64).sqrt()
    };
    assert!(
        rms(&slow) < rms(&fast),
        "400 ms: {} vs 25 ms: {}",
        rms(&slow),
        rms(&fast)
    );
    assert!(
        slow.iter().map(|r| r.device_seconds).sum::<f64>()
            > fast.iter().map(|r| r.device_seconds).sum::<f64>()
    );
}

#[test]
fn gonio_trade_writes_the_csv_the_summary_and_the_plot() {
    let dir = std::env::temp_dir().join(format!("gonio-trade-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let out = Command::new(env!("CARGO_BIN_EXE_gonio"))
        .args([
            "trade",
            "--quick",
            "--seeds",
            "1",
            "--out",
            dir.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let csv = std::fs::read_to_string(dir.join("trade.csv")).unwrap();
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    for column in [
        "policy",
        "setting",
        "sample",
        "seed",
        "integration_ms",
        "geometries",
        "device_seconds",
        "sigma_rel_err",
        "rho_s_rel_err",
        "rho_d_rel_err",
        "class_correct",
    ] {
        assert!(header.contains(&column), "no column {column}");
    }
    assert_eq!(lines.count(), trade::plan_runs(1, true).len());
    let summary = std::fs::read_to_string(dir.join("summary.md")).unwrap();
    assert!(
        summary.contains("The adaptive policy against the paper's")
            && summary.contains("Visiting order")
    );
    let svg = std::fs::read_to_string(dir.join("pareto.svg")).unwrap();
    assert!(svg.starts_with("<svg") && svg.contains("adaptive"));
    // Unresolved σ is a labelled band, not a "1000 %" error.
    assert!(
        svg.contains("σ unresolved") && !svg.contains("1000"),
        "the pareto plot's unresolved band"
    );
    // Bad input: a clear error, non-zero.
    let out = Command::new(env!("CARGO_BIN_EXE_gonio"))
        .args(["trade", "--seeds", "0", "--out", dir.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--seeds must be at least 1"));
    let _ = std::fs::remove_dir_all(&dir);
}

/// The design puts the next readings where σ is decided: on the flanks of the specular
/// peak, where the lobe still stands well above the noise (not in the flat diffuse part
/// further out, which the candidates reach), never on a geometry already measured.
#[test]
fn the_next_batch_goes_to_the_flanks_of_the_peak() {
    use host::analysis::fit::{FitOptions, Observation, fit};
    use protocol::Geometry;
    let g_paper = host::analysis::classify::REFERENCES[0].params;
    let acceptance = host::analysis::model::DEFAULT_ACCEPTANCE_DEG;
    let mut geometries: Vec<Geometry> = protocol::schedules::strategy1(12).unwrap().to_vec();
    geometries.extend(
        [-1.0, 1.0, -2.0, 2.0]
            .iter()
            .filter_map(|d| Geometry::from_deg(45.0, 45.0 + d)),
    );
    let observations: Vec<Observation> = geometries
        .iter()
        .map(|g| {
            let r = host::analysis::model::observed_radiance_factor(
                &g_paper,
                g.theta_i.deg(),
                g.theta_r.deg(),
                acceptance,
            );
            Observation {
                theta_i_deg: g.theta_i.deg(),
                theta_r_deg: g.theta_r.deg(),
                radiance_factor: r,
                std: Some(0.002 * r + 1e-4),
                theta_r_span_deg: 0.0,
            }
        })
        .collect();
    let result = fit(
        &observations,
        &FitOptions {
            acceptance_deg: Some(acceptance),
            ..FitOptions::default()
        },
    )
    .unwrap();
    assert!(host::session::adaptive::sigma_resolved(&result));
    let measured = geometries.iter().copied().collect();
    let motion = host::session::order::Motion::reference();
    let batch = host::session::adaptive::next_batch(
        &result,
        &observations,
        &measured,
        geometries[geometries.len() - 1],
        &motion,
        100,
        6,
    )
    .unwrap();
    assert_eq!(batch.len(), 6);
    for g in &batch {
        let r = host::analysis::model::observed_radiance_factor(
            &g_paper,
            g.theta_i.deg(),
            g.theta_r.deg(),
            acceptance,
        );
        let lobe = r - g_paper.rho_d;
        assert!(
            g.theta_r != g.theta_i && lobe > 10.0 * (0.002 * r + 1e-4),
            "{g:?}: the lobe ({lobe}) is lost in the noise there"
        );
        assert!(!measured.contains(g), "{g:?} measured twice");
    }
}

/// The sweep policy at its first setting (60 °/s, 0.1° bins) on every paper, 3 seeds
/// (`gonio trade` runs 20 and every setting, docs/TRADE.md): the class right in every
/// session, G's and SG's σ within 5 %, the glossy papers measured in less device time
/// than the adaptive policy takes, and every paper's sample time (homing and calibration
/// apart: less the ranges' gain calibration on the sample) within the 8 s, in the
/// mean and in the longest session. Device time is the simulated instrument's clock, the
/// reference kinematics', not this machine's.
#[test]
fn the_sweep_policy_gets_the_class_and_sigma_in_less_device_time() {
    let runs: Vec<RunSpec> = trade::plan_runs(3, true)
        .into_iter()
        .filter(|r| {
            (r.policy == "sweep" && r.setting == trade::SWEEP_SETTINGS[0])
                || (r.policy == "adaptive" && r.integration_ms == trade::TARGET_INTEGRATION_MS)
        })
        .collect();
    assert_eq!(runs.len(), 2 * 8 * 3);
    let rows = trade::run_all(&runs, 2, &|| {}).expect("every session completes");
    let checks = trade::sweep_checks(&rows);
    assert_eq!(checks.len(), 8);
    for c in &checks {
        println!(
            "{} {}: {:.1} s (max {:.1}, less gain calibration {:.1}, max {:.1}), adaptive {:.1} s",
            c.setting,
            c.sample,
            c.sweep.mean_device_seconds,
            c.max_device_seconds,
            c.mean_less_gain_calibration_seconds,
            c.max_less_gain_calibration_seconds,
            c.adaptive.as_ref().unwrap().mean_device_seconds
        );
        assert_eq!(c.sweep.class_accuracy, 1.0, "{}: {:?}", c.sample, c.sweep);
        assert!(
            c.time_met && c.max_less_gain_calibration_seconds <= trade::SWEEP_DEVICE_TARGET_S,
            "{}: {:.2} s at most",
            c.sample,
            c.max_less_gain_calibration_seconds
        );
        if c.sample == "G" || c.sample == "SG" {
            assert_eq!(c.sweep.sigma_within_target, 1.0, "{}", c.sample);
            assert!(
                c.sweep.mean_device_seconds < c.adaptive.as_ref().unwrap().mean_device_seconds,
                "{}: sweeps are faster than point readings",
                c.sample
            );
        }
    }
    let summary = trade::summary_markdown(&rows, 3, "");
    assert!(summary.contains("## Sweeps against their targets"));
}
