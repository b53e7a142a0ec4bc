//! The pty campaign in small (issue 30; the full one is `gonio reliability --pty 100`,
//! docs/RELIABILITY.md): the real `gonio measure` against `gonio sim` on a pseudo-terminal
//! with corrupt ≤ 0.01, drop ≤ 0.02 and an unplug at a drawn moment, a session under each
//! policy (sheets of 1–3 spots drawn); every one ends by itself within its stated bounds,
//! finished or with its reason. A new campaign seed every run (printed, to repeat a
//! failure).
use host::study::pty::{Ended, run_all, summary_markdown};
use std::path::Path;

#[test]
fn pty_sessions_on_a_bad_link_with_an_unplug_all_end_within_their_bounds_saying_how() {
    let seed = crate::common::run_seed();
    let base = std::env::temp_dir().join(format!("gonio-pty-test-{}", std::process::id()));
    let gonio = Path::new(env!("CARGO_BIN_EXE_gonio"));
    let started = std::time::Instant::now();
    let rows =
        run_all(3, seed, gonio, &base, 3, &|| {}).unwrap_or_else(|e| panic!("seed {seed}: {e}"));
    let summary = summary_markdown(&rows, seed, started.elapsed().as_secs_f64());
    eprintln!("{summary}");
    assert_eq!(rows.len(), 3, "seed {seed}: a session panicked");
    for row in &rows {
        assert!(row.failure.is_none(), "seed {seed}: {summary}");
        match &row.ended {
            Ended::Finished => assert!(row.spots_measured >= usize::from(row.spec.spots)),
            Ended::GaveUp(reason) | Ended::Bound(reason) => {
                assert!(!reason.is_empty(), "seed {seed}: {summary}")
            }
            other => panic!("seed {seed}: {other:?}: {summary}"),
        }
    }
    let _ = std::fs::remove_dir_all(&base);
}
