//! The interruption campaign in small (issue 30; the full one is `gonio reliability
//! --interruptions 300`, docs/RELIABILITY.md): sheets under every policy and the README's
//! main job interrupted one, two and three times in a row (kills and Ctrl-C at random
//! writes, give-ups), each resumed; every final folder verifies, every spot is under the
//! sheet's plan and nothing measured is lost. A new campaign seed every run (printed, to
//! repeat a failure).
use host::study::interruptions::{run_all, summary_markdown};
use std::path::Path;

#[test]
fn sheets_interrupted_one_two_and_three_times_resume_whole_under_their_plan() {
    let seed = crate::common::run_seed();
    let ram = Path::new("/dev/shm");
    let base = if ram.is_dir() {
        ram.to_path_buf()
    } else {
        std::env::temp_dir()
    }
    .join(format!("gonio-interruptions-test-{}", std::process::id()));
    // Nine sheets: every policy with one, two and three interruptions drawn, the README's
    // main job (`--sim G --policy sweep`, the default spots) among them.
    let rows = run_all(9, seed, &base, 2, &|| {}).unwrap_or_else(|e| panic!("seed {seed}: {e}"));
    let summary = summary_markdown(&rows, seed);
    eprintln!("{summary}");
    assert_eq!(rows.len(), 9, "seed {seed}: a session panicked");
    for row in &rows {
        assert!(row.failure.is_none(), "seed {seed}: {summary}");
    }
    assert!(
        rows.iter().any(|r| r.spec.main_job
            && r.spec.sample == "G"
            && r.spec.spots == host::measure::DEFAULT_SPOTS),
        "seed {seed}: the README's main job is not among the sheets: {summary}"
    );
    assert!(
        rows.iter().any(|r| r.happened.len() >= 2),
        "seed {seed}: no sheet was interrupted twice: {summary}"
    );
    let _ = std::fs::remove_dir_all(&base);
}
