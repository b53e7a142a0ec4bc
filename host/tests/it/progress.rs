//! What a person's terminal shows during a session, drawn to an in-memory terminal: a phase
//! line (not "0/0 geometries") before the first geometry, every decision and prompt printed
//! above one bar, and no frozen copy of the bar left behind.
use host::instrument::link::{Client, RetryPolicy};
use host::instrument::sim::SimOptions;
use host::output::folder::PlanRecord;
use host::output::folder::record::{FileRecorder, Identity, progress_bar_to};
use host::output::folder::store::StoreOptions;
use host::session::{Operator, Placement, Progress, PromptOperator, Recorder};
use indicatif::{InMemoryTerm, ProgressDrawTarget};
use std::time::Duration;

fn lines(term: &InMemoryTerm) -> Vec<String> {
    term.contents()
        .lines()
        .map(|l| l.trim_end().to_string())
        .filter(|l| !l.is_empty())
        .collect()
}

#[test]
fn decisions_and_prompts_go_above_one_bar_and_no_copy_is_left_behind() {
    let mut client = Client::new(
        SimOptions::default().instrument("G").unwrap(),
        RetryPolicy::default(),
    );
    let info = client.hello().unwrap();
    let plan = PlanRecord {
        policy: "adaptive".into(),
        adaptive_targets: None,
        sweep_targets: None,
        integration_ms: 100,
        acceptance_deg: 1.0,
        white_check: false,
        white_drift_limit_pct: 0.5,
        model: Some("extended".into()),
    };
    let dir = std::env::temp_dir().join(format!("gonio-progress-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let mut recorder = FileRecorder::create(
        &dir,
        Identity::new("G", &info, plan),
        StoreOptions::default(),
    )
    .unwrap();
    let term = InMemoryTerm::new(40, 140);
    recorder.bar = progress_bar_to(ProgressDrawTarget::term_like(Box::new(term.clone())));
    recorder.bar.tick();
    let screen = lines(&term);
    assert!(
        screen
            .last()
            .is_some_and(|l| l.contains("getting ready: homing")),
        "a phase line before any geometry: {screen:?}"
    );
    assert!(!term.contents().contains("0/0"), "no bar of 0/0 geometries");

    let mut person = PromptOperator::answered_on(std::io::Cursor::new(b"\n".to_vec()));
    person.attach_progress(&recorder.bar);
    recorder.decision("homing the arms");
    person.ask(Placement::WhiteTile, Duration::ZERO).unwrap();
    recorder.decision("the operator answered after 12.0 s");
    recorder.stage("strategy 1 (12 geometries)", 12);
    for done in 1..=5 {
        recorder.progress(Progress {
            done,
            planned: 12,
            remaining: Duration::from_secs(10 - done as u64),
        });
        recorder.decision(&format!("reading {done}"));
    }
    person
        .ask(Placement::NextSpot { spot: 2, of: 5 }, Duration::ZERO)
        .unwrap();
    recorder.progress(Progress {
        done: 6,
        planned: 12,
        remaining: Duration::from_secs(4),
    });

    let screen = lines(&term);
    let bars: Vec<&String> = screen
        .iter()
        .filter(|l| l.contains("geometries,"))
        .collect();
    assert_eq!(bars.len(), 1, "one bar, no frozen copies: {screen:#?}");
    assert!(
        screen.last().is_some_and(|l| l.contains("6/12 geometries")),
        "the bar is the last line: {screen:#?}"
    );
    assert!(
        !screen.iter().any(|l| l.contains("getting ready")),
        "the phase line is gone: {screen:#?}"
    );
    let at = |needle: &str| {
        screen
            .iter()
            .position(|l| l.contains(needle))
            .unwrap_or_else(|| panic!("{needle} on the screen: {screen:#?}"))
    };
    // In order, above the bar: decisions, the prompts whole.
    assert!(
        at("homing the arms") < at("WHITE REFERENCE TILE")
            && at("WHITE REFERENCE TILE") < at("answered after 12.0 s")
    );
    assert!(at("Press Enter when done") < at("reading 1") && at("reading 5") < at("spot 2 of 5"));
    recorder.bar.finish_and_clear();
    let _ = std::fs::remove_dir_all(&dir);
}
