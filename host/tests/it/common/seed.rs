//! The run's seed, one for every test of a run in both test crates (gonio-tests includes
//! this file by its path): a failure names it, and `GONIO_TEST_SEED` runs it again.

/// A seed for this run, printed (a failure names it), so the folders, documents and
/// sessions differ from run to run; `GONIO_TEST_SEED` sets it, to run a failure's seed
/// again.
pub fn run_seed() -> u64 {
    let seed = std::env::var("GONIO_TEST_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| {
            std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(1, |d| u64::from(d.subsec_nanos()))
                % 100_000
        });
    eprintln!("seed of this run: {seed} (GONIO_TEST_SEED={seed} runs it again)");
    seed
}
