//! Campaigns of whole simulated sessions.
pub mod accuracy;
pub mod forensic;
pub mod reliability;
pub mod trade;

use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

/// `work` on every item on `threads` threads, the results in the items' order; `progress`
/// is called after each. Sessions of a campaign are independent and take from a few ms to
/// a second each, so the items are handed out one at a time.
pub fn parallel<I: Sync, O: Send>(items: &[I], threads: usize, progress: &(dyn Fn() + Sync), work: impl Fn(&I) -> O + Sync) -> Vec<O> {
    let next = AtomicUsize::new(0);
    let results: Mutex<Vec<Option<O>>> = Mutex::new((0..items.len()).map(|_| None).collect());
    std::thread::scope(|scope| {
        for _ in 0..threads.max(1) {
            scope.spawn(|| {
                loop {
                    let k = next.fetch_add(1, Ordering::Relaxed);
                    let Some(item) = items.get(k) else { break };
                    let out = work(item);
                    if let Ok(mut results) = results.lock() {
                        results[k] = Some(out);
                    }
                    progress();
                }
            });
        }
    });
    // A worker that panicked leaves its item's result out (and poisons nothing else).
    results.into_inner().unwrap_or_else(|poisoned| poisoned.into_inner()).into_iter().flatten().collect()
}
