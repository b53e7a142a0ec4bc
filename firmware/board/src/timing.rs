//! The self-test's timing figures, measured on the running board.
//!
//! INTERRUPTS OFF. This crate is the `critical-section` implementation of the whole image
//! (instead of cortex-m's `critical-section-single-core`): every critical section, the
//! board's own (the step generators' and the ADC's state) and embassy's (its time driver,
//! executor queues, USB), masks interrupts as cortex-m's does (PRIMASK) and, the outermost
//! one, is timed by the DWT cycle counter from the mask to the unmask. The longest since
//! boot is what a step interrupt may have had to wait, so the self-test reports it against
//! the step deadline. Not timed: code that masks interrupts without a critical section
//! (`cortex_m::interrupt::free`, none in this image's code) and the fault handlers (they
//! never unmask). Before `main` starts the cycle counter it reads 0, so boot's sections
//! count as 0.
//!
//! STEP LATENESS is the step generators' own record (`StepChannel::worst_late_ticks`).

use core::sync::atomic::{AtomicU32, Ordering};
use cortex_m::peripheral::DWT;

/// When the outermost critical section began, cycles.
static ENTERED: AtomicU32 = AtomicU32::new(0);
/// The longest critical section since boot, cycles.
static LONGEST: AtomicU32 = AtomicU32::new(0);

struct TimedCriticalSection;
critical_section::set_impl!(TimedCriticalSection);

// SAFETY: single core; interrupts are masked from `acquire` to the `release` of the
// outermost section, so nothing else runs in between (the same contract as cortex-m's
// single-core implementation, which this replaces).
unsafe impl critical_section::Impl for TimedCriticalSection {
    unsafe fn acquire() -> bool {
        let was_enabled = cortex_m::register::primask::read().is_active();
        cortex_m::interrupt::disable();
        if was_enabled {
            ENTERED.store(DWT::cycle_count(), Ordering::Relaxed);
        }
        was_enabled
    }

    unsafe fn release(was_enabled: bool) {
        if was_enabled {
            let cycles = DWT::cycle_count().wrapping_sub(ENTERED.load(Ordering::Relaxed));
            // Interrupts are still masked: a plain load and store is the whole update.
            if cycles > LONGEST.load(Ordering::Relaxed) {
                LONGEST.store(cycles, Ordering::Relaxed);
            }
            // SAFETY: they were enabled when the outermost section began.
            unsafe { cortex_m::interrupt::enable() };
        }
    }
}

/// The longest section with interrupts masked since boot, µs (rounded up).
pub fn longest_interrupts_off_us() -> u32 {
    LONGEST
        .load(Ordering::Relaxed)
        .div_ceil(crate::SYSCLK_HZ / 1_000_000)
}
