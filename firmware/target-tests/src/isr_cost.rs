//! The step generator's interrupt-off work, counted in instructions on the Cortex-M4.
//!
//! On the board a step interrupt (P0) must preload its next segment within 12 µs of the
//! segment's start (`firmware::stepgen`). What can make it late is the other arm's step
//! interrupt (same priority, it waits for it) and a critical section (thread mode's
//! `StepChannel::run_profile` under the arm's lock; the ADC's ring pushes; embassy's). The
//! board measures the lateness itself (`gonio selftest`); this bounds the step generator's
//! share before any board exists: QEMU runs with `-icount shift=0` (one instruction, one
//! nanosecond of virtual time), SysTick counts virtual time, and the ratio is calibrated
//! here on a loop of known length. `.ci/qemu-tests` checks the figures against its budget.

use core::hint::black_box;
use cortex_m::peripheral::SYST;
use cortex_m::peripheral::syst::SystClkSource;
use firmware::motion::MoveProfile;
use firmware::stepgen::{Segment, Start, StepChannel, StepTimer};

/// A timer that records nothing and keeps the cycle count where a timely interrupt finds
/// it: each update runs exactly at its segment's start.
struct VirtualTimer {
    update: bool,
    now: u32,
    running_ticks: u32,
    preloaded_ticks: u32,
}

impl StepTimer for VirtualTimer {
    const CYCLES_PER_TICK: u32 = 96;

    fn preload(&mut self, segment: Segment) {
        self.preloaded_ticks = black_box(segment.ticks);
    }

    fn start(&mut self) {
        self.running_ticks = self.preloaded_ticks;
    }

    fn stop_at_end_of_segment(&mut self) {
        self.preloaded_ticks = 0;
    }

    fn take_update(&mut self) -> bool {
        core::mem::take(&mut self.update)
    }

    fn set_direction(&mut self, positive: bool) {
        black_box(positive);
    }

    fn enable_driver(&mut self) {}

    fn now_cycles(&self) -> u32 {
        self.now
    }
}

impl VirtualTimer {
    /// The running segment ended: the next one begins now.
    fn next_segment(&mut self) {
        self.now = self
            .now
            .wrapping_add(self.running_ticks * Self::CYCLES_PER_TICK);
        self.running_ticks = self.preloaded_ticks;
        self.update = true;
    }
}

/// SysTick, free-running down from its top, on the core clock.
fn start_systick(syst: &mut SYST) {
    syst.set_clock_source(SystClkSource::Core);
    syst.set_reload(0x00FF_FFFF);
    syst.clear_current();
    syst.enable_counter();
}

fn ticks_of(f: impl FnOnce()) -> u32 {
    let before = SYST::get_current();
    f();
    let after = SYST::get_current();
    before.wrapping_sub(after) & 0x00FF_FFFF
}

/// Instructions per SysTick tick: a loop of 2 instructions × `n` against SysTick.
fn instructions_per_tick() -> u32 {
    let n: u32 = 200_000;
    let ticks = ticks_of(|| {
        // SAFETY: a register countdown, no memory, no stack.
        unsafe {
            core::arch::asm!(
                "2:",
                "subs {0}, {0}, #1",
                "bne 2b",
                inout(reg) n => _,
                options(nomem, nostack),
            );
        }
    });
    (2 * n).div_ceil(ticks.max(1))
}

/// The largest instruction counts seen.
pub struct Cost {
    /// One update interrupt's work (`StepChannel::on_update`), a segment of a running
    /// profile.
    pub on_update: u32,
    /// The update interrupt that takes over a profile handed over (computes where the new
    /// one stands).
    pub on_update_handover: u32,
    /// A profile handed over under the arm's lock, its start prepared before
    /// (`StepChannel::run_prepared`, from rest or while moving): the critical section.
    pub run_profile: u32,
    /// The preparation of a start (`Start::prepare`), outside the lock: for the record.
    pub prepare: u32,
    /// Update interrupts measured.
    pub updates: u32,
    /// Instructions per SysTick tick (the resolution of each figure).
    pub resolution: u32,
}

/// Run long and short moves at the reference limits, each with a stop and a reversal
/// handed over mid-move, and keep the most instructions any call took.
pub fn measure(syst: &mut SYST) -> Cost {
    start_systick(syst);
    let per_tick = instructions_per_tick();
    let (vmax, accel) = (4_800.0, 14_400.0);
    let mut cost = Cost {
        on_update: 0,
        on_update_handover: 0,
        run_profile: 0,
        prepare: 0,
        updates: 0,
        resolution: per_tick,
    };
    for (target, handover) in [
        (6_800, 3_000u32),
        (400, 200),
        (-2_000, 1_500),
        (6_800, 9_000),
    ] {
        let mut channel = StepChannel::new();
        let mut timer = VirtualTimer {
            update: false,
            now: 0,
            running_ticks: 0,
            preloaded_ticks: 0,
        };
        let profile = MoveProfile::fastest(0, target, 0.0, vmax, accel);
        let mut start = None;
        let ticks = ticks_of(|| start = black_box(Start::prepare(&profile)));
        cost.prepare = cost.prepare.max(ticks * per_tick);
        let ticks = ticks_of(|| channel.run_prepared(&mut timer, &profile, start));
        cost.run_profile = cost.run_profile.max(ticks * per_tick);
        let mut updates = 0u32;
        let mut handed_over = false;
        while channel.is_moving() && updates < 100_000 {
            timer.next_segment();
            let ticks = ticks_of(|| channel.on_update(&mut timer));
            if core::mem::take(&mut handed_over) {
                cost.on_update_handover = cost.on_update_handover.max(ticks * per_tick);
            } else {
                cost.on_update = cost.on_update.max(ticks * per_tick);
            }
            updates += 1;
            if updates == handover {
                // A stop at full deceleration, then (at the next handover) a reversal.
                let here = channel.position();
                let back =
                    MoveProfile::fastest(here, here - target.signum() * 500, 0.0, vmax, accel);
                let start = Start::prepare(&back);
                let ticks = ticks_of(|| channel.run_prepared(&mut timer, &back, start));
                cost.run_profile = cost.run_profile.max(ticks * per_tick);
                handed_over = true;
            }
        }
        cost.updates += updates;
    }
    cost
}
