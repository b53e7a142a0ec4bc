//! Step pulses from hardware timers: TIM2 drives the source arm's STEP (PB10, TIM2_CH3),
//! TIM3 the detector arm's (PB0, TIM3_CH3). No busy loop, no async wake per step.
//!
//! How: the timer counts 1 µs ticks in PWM mode 1 with ARR and CCR3 preloaded. Each timer
//! period is a *segment* that starts with a step pulse (CCR3 = [`PULSE_TICKS`]) or without
//! one (CCR3 = 0). The update interrupt fires when a segment starts (the hardware has just
//! loaded it from the preload registers and raised STEP): it counts the step if the
//! segment has one and writes the segment after it into the preload registers. So the
//! pulse edges come from the hardware, and the interrupt only has to run at some time
//! during the segment (≥ 208 µs at 4,800 steps/s) for the timing to stay exact.
//!
//! Segment lengths come from the library's profile: `step_time_us(k + 1) − step_time_us(k)`.
//! Gaps longer than the 16-bit counter (65.5 ms, slow steps of a scaled-down arm) are
//! split into several segments, only the first with a pulse. After the last step's pulse
//! comes one tail segment in one-pulse mode (the counter stops by itself, STEP low); its
//! end clears `is_moving`, [`TAIL_TICKS`] after the last step was issued.
//!
//! ISR cost (no hardware here to measure it; counted from the disassembly of the
//! release ELF): `MoveProfile::step_time_us` is ~105 instructions with one VDIV (14
//! cycles), one libm `sqrtf` (a software square root, not VSQRT: ~66 instructions and 3
//! helper calls, ≈ 120 cycles) and one `__aeabi_f2ulz` (≈ 40 cycles): ≈ 300 cycles worst
//! case, once per step. `on_update` itself is ~100 instructions (critical section, ~8
//! timer register accesses on APB1, the segment bookkeeping), plus ~30 cycles of entry
//! and exit with lazy FPU stacking: ≲ 500 cycles ≈ 5 µs per step at 96 MHz. Both arms at
//! full speed: 9,600 steps/s × 500 ≈ 4.8 M cycles/s, ≈ 5 % of the CPU, and 5 µs of a
//! 208 µs step period; so no incremental step-time method in the library was needed.
//! (A DWT cycle count on the board would confirm it.)
//!
//! Assumptions the timing relies on: nothing masks interrupts for a whole segment
//! (embassy's critical sections last microseconds), and no segment is shorter than the
//! worst interrupt latency ([`MIN_SEGMENT_TICKS`], [`TAIL_TICKS`]). A late interrupt would
//! let the hardware repeat the previous segment (an uncounted step).

use core::cell::RefCell;
use core::sync::atomic::{AtomicBool, AtomicI32, Ordering};

use embassy_stm32::Peri;
use embassy_stm32::gpio::{Level, Output, OutputType};
use embassy_stm32::interrupt;
use embassy_stm32::interrupt::{InterruptExt, Priority};
use embassy_stm32::pac;
use embassy_stm32::pac::timer::{TimGp16, vals};
use embassy_stm32::peripherals::{PB0, PB10, TIM2, TIM3};
use embassy_stm32::timer::low_level::Timer;
use embassy_stm32::timer::simple_pwm::PwmPin;
use embassy_stm32::timer::{Ch3, GeneralInstance4Channel};
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use firmware::Arm;
use firmware::motion::MoveProfile;

/// Timer tick: 1 µs, the unit of `MoveProfile::step_time_us`.
const TICK_HZ: u32 = 1_000_000;
/// STEP high time, ticks (TMC2209: ≥ 100 ns).
const PULSE_TICKS: u16 = 2;
/// Shortest segment: keeps a rounding artefact from asking for a period shorter than the
/// pulse or than the interrupt latency (full speed is 208 µs per step).
const MIN_SEGMENT_TICKS: u32 = 20;
/// Longest segment: ARR is 16 bits (TIM3; TIM2 is used the same way) and counts 0..=ARR.
const MAX_SEGMENT_TICKS: u32 = 1 << 16;
/// The segment after the last step: long enough for its interrupt to set one-pulse mode
/// in time (the same latency margin as a step at full speed).
const TAIL_TICKS: u32 = 200;
/// CCR/CCMR index of channel 3.
const CH3: usize = 2;

/// One timer period.
#[derive(Clone, Copy)]
struct Segment {
    ticks: u32,
    pulse: bool,
}

/// Turns a profile into segments, one step time computed per step.
#[derive(Clone, Copy)]
struct StepGen {
    profile: MoveProfile,
    count: u32,
    /// The step whose time ends the segment being generated (count + 1 after the last).
    next_step: u32,
    /// `step_time_us(next_step)`.
    next_time_us: u64,
    /// Where the segments generated so far end, µs after the start.
    planned_us: u64,
    /// The next segment starts with a step pulse.
    pulse_next: bool,
}

impl StepGen {
    fn new(profile: &MoveProfile) -> StepGen {
        StepGen {
            profile: *profile,
            count: profile.step_count(),
            next_step: 1,
            next_time_us: profile.step_time_us(1),
            planned_us: 0,
            pulse_next: false,
        }
    }

    fn next(&mut self) -> Option<Segment> {
        let pulse = core::mem::replace(&mut self.pulse_next, false);
        if self.next_step > self.count {
            // The last step's pulse, then nothing.
            return pulse.then_some(Segment {
                ticks: TAIL_TICKS,
                pulse: true,
            });
        }
        let gap = self.next_time_us.saturating_sub(self.planned_us);
        if gap > u64::from(MAX_SEGMENT_TICKS) {
            self.planned_us += u64::from(MAX_SEGMENT_TICKS);
            return Some(Segment {
                ticks: MAX_SEGMENT_TICKS,
                pulse,
            });
        }
        let ticks = (gap as u32).max(MIN_SEGMENT_TICKS);
        self.planned_us += u64::from(ticks);
        self.next_step += 1;
        if self.next_step <= self.count {
            self.next_time_us = self.profile.step_time_us(self.next_step);
        }
        self.pulse_next = true;
        Some(Segment { ticks, pulse })
    }
}

/// What the interrupt of one arm's timer works on.
struct Run {
    generator: Option<StepGen>,
    /// The segment in the preload registers: `Some(has a pulse)`, or `None` when the
    /// running segment is the last (one-pulse mode set) or the timer is idle.
    preloaded: Option<bool>,
    /// +1 or −1: what each pulse adds to the position.
    direction: i32,
}

static RUNS: [Mutex<CriticalSectionRawMutex, RefCell<Run>>; 2] = [
    Mutex::new(RefCell::new(Run::IDLE)),
    Mutex::new(RefCell::new(Run::IDLE)),
];
/// Step counts, one per pulse issued (signed by direction).
static POSITION: [AtomicI32; 2] = [AtomicI32::new(0), AtomicI32::new(0)];
/// A profile is running (until its tail segment ends).
static MOVING: [AtomicBool; 2] = [AtomicBool::new(false), AtomicBool::new(false)];

impl Run {
    const IDLE: Run = Run {
        generator: None,
        preloaded: None,
        direction: 0,
    };
}

/// The registers of arm `index`'s step timer.
fn timer(index: usize) -> TimGp16 {
    if index == 0 {
        // SAFETY: TIM2 is a 32-bit general-purpose timer whose register block is a superset
        // of the 16-bit one at the same offsets (embassy's `regs_gp16` does the same); we
        // use only 16-bit ARR/CCR values, so writing these registers is well defined.
        unsafe { TimGp16::from_ptr(pac::TIM2.as_ptr()) }
    } else {
        pac::TIM3
    }
}

/// Write `segment` into the preload registers (it starts at the next update event).
fn preload(tim: TimGp16, segment: Segment) {
    tim.arr().write(|w| w.set_arr((segment.ticks - 1) as u16));
    let ccr = if segment.pulse { PULSE_TICKS } else { 0 };
    tim.ccr(CH3).write(|w| w.set_ccr(ccr));
}

/// The update interrupt of arm `index`: a segment has just started.
fn on_update(index: usize) {
    let tim = timer(index);
    if !tim.sr().read().uif() {
        return; // already accounted for by `halt`
    }
    tim.sr().modify(|w| w.set_uif(false));
    RUNS[index].lock(|run| {
        let run = &mut *run.borrow_mut();
        let Some(pulse) = run.preloaded.take() else {
            // The tail segment ended and one-pulse mode stopped the counter.
            run.generator = None;
            tim.dier().modify(|w| w.set_uie(false));
            MOVING[index].store(false, Ordering::Release);
            return;
        };
        if pulse {
            POSITION[index].fetch_add(run.direction, Ordering::Relaxed);
        }
        match run.generator.as_mut().and_then(StepGen::next) {
            Some(next) => {
                preload(tim, next);
                run.preloaded = Some(next.pulse);
            }
            None => {
                // The running segment is the last: stop at its end with STEP low.
                tim.ccr(CH3).write(|w| w.set_ccr(0));
                tim.cr1().modify(|w| w.set_opm(true));
            }
        }
    });
}

#[interrupt]
fn TIM2() {
    on_update(0);
}

#[interrupt]
fn TIM3() {
    on_update(1);
}

/// Stop arm `index`'s timer now, without cutting a step pulse short, and count a pulse
/// whose interrupt has not run yet. Called with the arm's `Run` locked (interrupts off).
fn halt(tim: TimGp16, run: &mut Run, index: usize) {
    if tim.cr1().read().cen() {
        // At most PULSE_TICKS µs: wait until STEP is low again (CNT restarts at each
        // segment, and every segment is far longer than the pulse).
        while tim.cnt().read().cnt() < PULSE_TICKS {}
        tim.cr1().modify(|w| w.set_cen(false));
    }
    if tim.sr().read().uif() {
        tim.sr().modify(|w| w.set_uif(false));
        if run.preloaded == Some(true) {
            POSITION[index].fetch_add(run.direction, Ordering::Relaxed);
        }
    }
    *run = Run::IDLE;
    tim.dier().modify(|w| w.set_uie(false));
    MOVING[index].store(false, Ordering::Release);
}

/// The two step generators with their DIR and EN outputs.
pub struct Steppers {
    _timers: (Timer<'static, TIM2>, Timer<'static, TIM3>),
    _step_pins: (PwmPin<'static, TIM2, Ch3>, PwmPin<'static, TIM3, Ch3>),
    dir: [Output<'static>; 2],
    /// TMC2209 EN, active low.
    en: [Output<'static>; 2],
}

/// Prescaler, PWM mode 1 on CH3 with preload, STEP low, update interrupt unmasked.
fn init_timer<T: GeneralInstance4Channel>(tim: &Timer<'static, T>, irq: interrupt::Interrupt) {
    let regs = tim.regs_gp16();
    let psc = tim.get_clock_frequency().0 / TICK_HZ - 1; // 96 MHz timer clock → 95
    regs.psc().write_value(psc as u16);
    regs.cr1().write(|w| {
        w.set_arpe(true);
        w.set_urs(vals::Urs::COUNTER_ONLY); // UG loads registers without an interrupt
    });
    regs.ccmr_output(CH3 / 2).modify(|w| {
        w.set_ocm(CH3 % 2, vals::Ocm::PWM_MODE1);
        w.set_ocpe(CH3 % 2, true);
    });
    regs.ccr(CH3).write(|w| w.set_ccr(0));
    regs.arr().write(|w| w.set_arr(u16::MAX));
    regs.egr().write(|w| w.set_ug(true));
    regs.ccer().modify(|w| w.set_cce(CH3, true));
    irq.unpend();
    // Highest priority: a step interrupt must run within its segment.
    irq.set_priority(Priority::P0);
    // SAFETY: the handlers for TIM2/TIM3 are defined above and share state only
    // through critical-section mutexes and atomics.
    unsafe { irq.enable() };
}

impl Steppers {
    /// Take the step timers and the STEP/DIR/EN pins; drivers stay disabled until the
    /// first move.
    pub fn new(
        tim2: Peri<'static, TIM2>,
        tim3: Peri<'static, TIM3>,
        step_i: Peri<'static, PB10>,
        step_r: Peri<'static, PB0>,
        dir: [Output<'static>; 2],
        en: [Output<'static>; 2],
    ) -> Steppers {
        let timers = (Timer::new(tim2), Timer::new(tim3));
        init_timer(&timers.0, interrupt::TIM2);
        init_timer(&timers.1, interrupt::TIM3);
        // The channels drive low now, so the pins switch to the timer without a glitch.
        let step_pins = (
            PwmPin::new(step_i, OutputType::PushPull),
            PwmPin::new(step_r, OutputType::PushPull),
        );
        Steppers {
            _timers: timers,
            _step_pins: step_pins,
            dir,
            en,
        }
    }

    /// Start `profile` on `arm`, replacing what it ran. The step count carries on from the
    /// pulses actually issued.
    pub fn run_profile(&mut self, arm: Arm, profile: &MoveProfile) {
        let index = arm.index();
        let tim = timer(index);
        let direction = profile.direction();
        RUNS[index].lock(|run| {
            let run = &mut *run.borrow_mut();
            halt(tim, run, index);
            if profile.step_count() == 0 {
                return;
            }
            // DIR high = positive steps. Set while STEP is low, ≥ 20 µs before the first
            // pulse (TMC2209 needs 20 ns).
            self.dir[index].set_level(Level::from(direction > 0));
            self.en[index].set_low();
            let mut generator = StepGen::new(profile);
            // The first segment is the wait for step 1 (no pulse); a profile with steps
            // always has a second one (step 1's pulse).
            let (Some(first), Some(second)) = (generator.next(), generator.next()) else {
                return;
            };
            tim.cr1().modify(|w| w.set_opm(false));
            preload(tim, first);
            tim.egr().write(|w| w.set_ug(true)); // load it now, CNT = 0
            preload(tim, second);
            tim.sr().modify(|w| w.set_uif(false));
            *run = Run {
                generator: Some(generator),
                preloaded: Some(second.pulse),
                direction,
            };
            MOVING[index].store(true, Ordering::Release);
            tim.dier().modify(|w| w.set_uie(true));
            tim.cr1().modify(|w| w.set_cen(true));
        });
    }

    /// Steps issued, signed, from the zero homing defined.
    pub fn position_steps(&self, arm: Arm) -> i32 {
        POSITION[arm.index()].load(Ordering::Relaxed)
    }

    /// A profile is still running.
    pub fn is_moving(&self, arm: Arm) -> bool {
        MOVING[arm.index()].load(Ordering::Acquire)
    }

    /// Redefine the count (arm at rest).
    pub fn set_position_steps(&mut self, arm: Arm, steps: i32) {
        POSITION[arm.index()].store(steps, Ordering::Relaxed);
    }
}
