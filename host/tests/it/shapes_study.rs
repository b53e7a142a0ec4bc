//! The campaign of sheets that are not TSL in small (`gonio accuracy --shapes 20` runs it at
//! full size, `host/src/study/shapes.rs`): two papers, the exact-TSL control and three
//! departures, one seed, the adaptive policy (a sweep session's 1,400 readings take the
//! fit's extension tests seconds each: the campaign runs them). What holds whatever the fit does with a departure
//! is asserted: every session finishes, the controls get the paper's class and no
//! extension, each departure reaches the simulated sheet (its session reads otherwise than
//! its control on the same seed), the tallies add up, and the files say what was run. The
//! targets themselves (class right in ≥ 90 %, coverage 90–98 %, …) need the campaign's
//! counts.
use super::cli_support::{gonio, stderr, temp_dir};
use host::instrument::sim::LobeChoice;
use host::session::PolicyChoice;
use host::study::shapes::{self, Design, Kind, Shape, Strength, Tally};

#[test]
fn sheets_that_are_not_tsl_in_small() {
    let departures = [
        Shape::Departure(Kind::Haze, Strength::Strong),
        Shape::Departure(Kind::OrenNayar, Strength::Strong),
        Shape::Departure(Kind::Lobe(LobeChoice::BlinnPhong), Strength::Strong),
    ];
    let design = Design {
        shapes: std::iter::once(Shape::Tsl).chain(departures).collect(),
        papers: vec!["G", "J1"],
        policies: vec![PolicyChoice::Adaptive],
        seeds: 1,
        first_index: 0,
    };
    let threads = std::thread::available_parallelism().map_or(2, |n| n.get());
    let campaign = shapes::run(&design, threads, &|| {}).expect("every session ran");
    assert_eq!(campaign.rows.len(), 4 * 2);
    assert!(campaign.not_applicable.is_empty());
    for r in &campaign.rows {
        let what = format!(
            "{} on {} ({})",
            r.spec.shape.name(),
            r.spec.paper,
            r.spec.policy.name()
        );
        assert_eq!(r.failure, None, "{what}");
        assert!(r.truth.is_some(), "{what}: no truth");
        if r.spec.shape == Shape::Tsl {
            assert!(
                r.class_right(),
                "{what}: {:?} at {:.2}",
                r.class,
                r.confidence
            );
            assert!(!r.extended(), "{what}: an extension on the exact TSL sheet");
            continue;
        }
        // The departure reached the sheet: on the control's seed it reads otherwise.
        let control = campaign
            .rows
            .iter()
            .find(|c| {
                c.spec.shape == Shape::Tsl
                    && c.spec.paper == r.spec.paper
                    && c.spec.policy == r.spec.policy
            })
            .expect("a control");
        assert_eq!(
            control.spec.seed, r.spec.seed,
            "{what}: not the control's seed"
        );
        assert!(
            control.estimates != r.estimates || control.geometries != r.geometries,
            "{what}: the same result as the exact TSL sheet"
        );
    }
    // The tallies add up: per shape to the whole, and within a tally.
    let whole = Tally::of(&campaign.rows);
    let mut sessions = 0;
    for &shape in &design.shapes {
        let t = Tally::of(campaign.rows.iter().filter(|r| r.spec.shape == shape));
        assert_eq!(t.sessions, 2, "{}", shape.name());
        // Right, or wrong (none) and flagged, or wrong (none) and said otherwise: disjoint.
        let unflagged_wrong = campaign
            .rows
            .iter()
            .filter(|r| r.spec.shape == shape && !r.class_right() && !r.flagged())
            .count();
        assert_eq!(
            t.class_right + t.flagged_wrong + unflagged_wrong,
            t.finished()
        );
        assert!(t.flagged_wrong <= t.flagged && t.confidently_wrong <= unflagged_wrong);
        assert!(t.gross_unflagged_miss <= t.unflagged_miss);
        sessions += t.sessions;
    }
    assert_eq!(sessions, whole.sessions);
    let summary = shapes::summary_markdown(&campaign);
    for shape in &design.shapes {
        assert!(
            summary.contains(&format!("| {} | adaptive |", shape.name())),
            "{summary}"
        );
    }
    assert!(
        summary.contains("exact TSL, adaptive policy: device time"),
        "{summary}"
    );
    let csv = shapes::to_csv(&campaign);
    assert_eq!(csv.lines().count(), 1 + campaign.rows.len());
    assert!(csv.contains(",--departure haze:0.03:4,G,"), "{csv}");
    assert!(csv.contains(",--lobe blinn-phong,J1,"), "{csv}");
    // Every session's final fit fitted the paper's model and its lobe shape at least, each
    // with σ's own interval around its estimate, and members.csv has a line for each member.
    for r in &campaign.rows {
        for label in ["TSL", "TSL + lobe shape"] {
            let m = r.members.iter().find(|m| m.label == label);
            let ci = m.and_then(|m| m.sigma_ci95.map(|(lo, hi)| (lo, m.sigma_deg, hi)));
            assert!(
                ci.is_some_and(|(lo, sigma, hi)| lo <= sigma && sigma <= hi),
                "{} on {}: {label} {m:?}",
                r.spec.shape.name(),
                r.spec.paper
            );
        }
    }
    let members = shapes::members_csv(&campaign);
    let lines: usize = campaign.rows.iter().map(|r| r.members.len()).sum();
    assert_eq!(members.lines().count(), 1 + lines);
    assert!(
        summary.contains("| blinn-phong strong | J1 | adaptive | 1 |"),
        "{summary}"
    );
}

/// One session is the same whenever it runs: its seed is its paper's, policy's and index's.
#[test]
fn a_shapes_session_repeats_exactly() {
    let spec = shapes::SessionSpec {
        shape: Shape::Departure(Kind::Retro, Strength::Strong),
        paper: "PPC",
        policy: PolicyChoice::Adaptive,
        index: 0,
        seed: Design::seed("PPC", PolicyChoice::Adaptive, 0),
    };
    assert_eq!(shapes::run_one(&spec), shapes::run_one(&spec));
}

#[test]
fn gonio_accuracy_shapes_refuses_what_it_cannot_run() {
    let out_dir = temp_dir("shapes-study", "refused");
    let out = out_dir.to_str().expect("a UTF-8 path");
    for (args, says) in [
        (
            vec![
                "accuracy",
                "--shapes",
                "1",
                "--departures",
                "fog",
                "--out",
                out,
            ],
            "--departures: no departure 'fog': use haze, peak-shift, ggx",
        ),
        (
            vec!["accuracy", "--shapes", "0", "--out", out],
            "--shapes must be at least 1",
        ),
        (
            vec!["accuracy", "--departures", "haze", "--out", out],
            "--shapes",
        ),
        (
            vec![
                "accuracy",
                "--shapes",
                "1",
                "--instruments",
                "1",
                "--out",
                out,
            ],
            "cannot be used with",
        ),
    ] {
        let run = gonio(&args);
        assert!(!run.status.success(), "{args:?} ran");
        assert!(stderr(&run).contains(says), "{args:?}: {}", stderr(&run));
    }
    assert!(!out_dir.exists(), "a refused campaign wrote its folder");
}
