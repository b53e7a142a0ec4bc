//! Step pulses from hardware timers: TIM2 drives the source arm's STEP (PB10, TIM2_CH3),
//! TIM3 the detector arm's (PB0, TIM3_CH3). No busy loop, no async wake per step.
//!
//! The logic (segments, the runt-free replacement of a running profile, the late-interrupt
//! check) is the library's [`firmware::stepgen::StepChannel`]; this module is its
//! [`StepTimer`]: the registers of one timer in PWM mode 1 at 1 µs ticks with ARR and CCR3
//! preloaded, the arm's DIR and EN pins, and the DWT cycle counter as the free-running
//! clock (96 cycles per tick: the CPU and the timer run from the same PLL, so the
//! interrupt's deadline check does not drift). Each channel and its pins sit behind a
//! critical-section mutex shared by the timer's update interrupt and the device task.
//!
//! ISR cost (no hardware here to measure it; counted from the disassembly of the
//! release ELF before the move into the library): `MoveProfile::step_time_us` ≈ 300 cycles
//! worst case (one VDIV, one software `sqrtf`, one float-to-u64), the bookkeeping and ~8
//! timer register accesses on APB1 ≲ 200 more: ≲ 500 cycles ≈ 5 µs per step at 96 MHz,
//! ≈ 5 % of the CPU with both arms at full speed, within `LATE_MARGIN_TICKS` (8 µs).
//!
//! Interrupt priority P0, above everything else (TIM5 P1, USB P2, the time driver P3):
//! a step interrupt has its segment (≥ 20 µs, 208 µs at full speed) to run. Critical
//! sections (embassy's, defmt-rtt's) still mask it; one that lasts longer than a segment is
//! caught by the deadline check and stops the arm ([`firmware::stepgen`]).

use core::cell::RefCell;
use core::sync::atomic::{AtomicI32, Ordering};

use cortex_m::peripheral::DWT;
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
use firmware::stepgen::{Segment, Start, StepChannel, StepFault, StepTimer};

/// Timer tick: 1 µs, the unit of `MoveProfile::step_time_us`.
const TICK_HZ: u32 = 1_000_000;
/// CPU cycles (DWT) per timer tick: SYSCLK 96 MHz (`main::clock_config`).
const CYCLES_PER_TICK: u32 = crate::SYSCLK_HZ / TICK_HZ;
/// CCR/CCMR index of channel 3.
const CH3: usize = 2;

/// One arm's step generator and the pins it drives.
struct Arm1 {
    channel: StepChannel,
    dir: Output<'static>,
    /// TMC2209 EN, active low.
    en: Output<'static>,
    /// The last late interrupt, for the log.
    fault: Option<StepFault>,
}

static ARMS: [Mutex<CriticalSectionRawMutex, RefCell<Option<Arm1>>>; 2] = [
    Mutex::new(RefCell::new(None)),
    Mutex::new(RefCell::new(None)),
];

/// The detector arm's step count, mirrored from its channel whenever it changes (its step
/// interrupt, a redefinition), so that the ADC's decimation interrupt (TIM5, P1) stamps
/// each block with one atomic load instead of a critical section that would hold off the
/// step interrupts (P0).
static DETECTOR_STEPS: AtomicI32 = AtomicI32::new(0);

/// The detector arm's step count now (one load; any context).
pub(crate) fn detector_steps() -> i32 {
    DETECTOR_STEPS.load(Ordering::Relaxed)
}

/// The registers of arm `index`'s step timer.
pub(crate) fn timer(index: usize) -> TimGp16 {
    if index == 0 {
        // SAFETY: TIM2 is a 32-bit general-purpose timer whose register block is a superset
        // of the 16-bit one at the same offsets (embassy's `regs_gp16` does the same); we
        // use only 16-bit ARR/CCR values, so writing these registers is well defined.
        unsafe { TimGp16::from_ptr(pac::TIM2.as_ptr()) }
    } else {
        pac::TIM3
    }
}

/// [`StepTimer`] on one timer and its arm's pins.
struct BoardTimer<'a> {
    tim: TimGp16,
    dir: &'a mut Output<'static>,
    en: &'a mut Output<'static>,
}

impl StepTimer for BoardTimer<'_> {
    const CYCLES_PER_TICK: u32 = CYCLES_PER_TICK;

    fn preload(&mut self, segment: Segment) {
        self.tim
            .arr()
            .write(|w| w.set_arr((segment.ticks - 1) as u16));
        // The STEP high time of this build's driver modules (`crate::driver`).
        let ccr = if segment.pulse {
            crate::driver::DRIVER.step_pulse_ticks
        } else {
            0
        };
        self.tim.ccr(CH3).write(|w| w.set_ccr(ccr));
    }

    fn start(&mut self) {
        self.tim.cr1().modify(|w| w.set_opm(false));
        // UG loads the preloaded segment, CNT = 0; no interrupt (URS = counter only).
        self.tim.egr().write(|w| w.set_ug(true));
        self.tim.sr().modify(|w| w.set_uif(false));
        self.tim.cr1().modify(|w| w.set_cen(true));
    }

    fn stop_at_end_of_segment(&mut self) {
        self.tim.ccr(CH3).write(|w| w.set_ccr(0));
        self.tim.cr1().modify(|w| w.set_opm(true));
    }

    fn take_update(&mut self) -> bool {
        if !self.tim.sr().read().uif() {
            return false;
        }
        self.tim.sr().modify(|w| w.set_uif(false));
        true
    }

    fn set_direction(&mut self, positive: bool) {
        // DIR high = positive steps.
        self.dir.set_level(Level::from(positive));
    }

    fn enable_driver(&mut self) {
        self.en.set_low();
    }

    fn now_cycles(&self) -> u32 {
        DWT::cycle_count()
    }
}

/// With arm `index`'s channel and its timer.
fn with_arm<R>(
    index: usize,
    f: impl FnOnce(&mut StepChannel, &mut BoardTimer<'_>, &mut Option<StepFault>) -> R,
) -> Option<R> {
    ARMS[index].lock(|arm| {
        let mut arm = arm.borrow_mut();
        let arm = arm.as_mut()?;
        let mut timer = BoardTimer {
            tim: timer(index),
            dir: &mut arm.dir,
            en: &mut arm.en,
        };
        Some(f(&mut arm.channel, &mut timer, &mut arm.fault))
    })
}

/// The update interrupt of arm `index`: a segment has just started.
fn on_update(index: usize) {
    with_arm(index, |channel, timer, fault| {
        channel.on_update(timer);
        if let Some(late) = channel.take_fault() {
            fault.get_or_insert(late);
        }
        if index == Arm::Detector.index() {
            DETECTOR_STEPS.store(channel.position(), Ordering::Relaxed);
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

/// The two step generators with their DIR and EN outputs.
pub struct Steppers {
    _timers: (Timer<'static, TIM2>, Timer<'static, TIM3>),
    _step_pins: (PwmPin<'static, TIM2, Ch3>, PwmPin<'static, TIM3, Ch3>),
}

/// Prescaler, PWM mode 1 on CH3 with preload, STEP low, update interrupt on.
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
    regs.sr().modify(|w| w.set_uif(false));
    // The interrupt runs only on counter overflows, i.e. while a move runs.
    regs.dier().modify(|w| w.set_uie(true));
    irq.unpend();
    // Highest priority: a step interrupt must run within its segment.
    irq.set_priority(Priority::P0);
    // SAFETY: the handlers for TIM2/TIM3 are defined above and share state only
    // through critical-section mutexes.
    unsafe { irq.enable() };
}

impl Steppers {
    /// Take the step timers and the STEP/DIR/EN pins; drivers stay disabled until the
    /// first move. The DWT cycle counter must run (`main` starts it).
    pub fn new(
        tim2: Peri<'static, TIM2>,
        tim3: Peri<'static, TIM3>,
        step_i: Peri<'static, PB10>,
        step_r: Peri<'static, PB0>,
        dir: [Output<'static>; 2],
        en: [Output<'static>; 2],
    ) -> Steppers {
        let [dir_i, dir_r] = dir;
        let [en_i, en_r] = en;
        for (index, (dir, en)) in [(dir_i, en_i), (dir_r, en_r)].into_iter().enumerate() {
            ARMS[index].lock(|arm| {
                *arm.borrow_mut() = Some(Arm1 {
                    channel: StepChannel::new(),
                    dir,
                    en,
                    fault: None,
                });
            });
        }
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
        }
    }

    /// Run `profile` on `arm` (from rest at once; while moving, after the committed
    /// segments: see `firmware::stepgen`).
    pub fn run_profile(&mut self, arm: Arm, profile: &MoveProfile) {
        // The start's arithmetic before the lock: interrupts are masked only for the
        // hand-over (`firmware::stepgen::StepChannel::run_prepared`).
        let start = Start::prepare(profile);
        with_arm(arm.index(), |channel, timer, _| {
            channel.run_prepared(timer, profile, start)
        });
    }

    /// Run `profile`'s pulses on `arm` with its driver left disabled (the self-test's
    /// pulse check: `firmware::selftest`).
    pub fn run_pulse_check(&mut self, arm: Arm, profile: &MoveProfile) {
        let start = Start::prepare(profile);
        with_arm(arm.index(), |channel, timer, _| {
            channel.run_pulse_check(timer, start)
        });
    }

    /// The latest `arm`'s step interrupt ran after its segment began since boot, ticks
    /// (µs).
    pub fn worst_late_ticks(&self, arm: Arm) -> u32 {
        with_arm(arm.index(), |channel, _, _| channel.worst_late_ticks()).unwrap_or(0)
    }

    /// Steps issued, signed, from the zero homing defined.
    pub fn position_steps(&self, arm: Arm) -> i32 {
        with_arm(arm.index(), |channel, _, _| channel.position()).unwrap_or(0)
    }

    /// A profile is still running.
    pub fn is_moving(&self, arm: Arm) -> bool {
        with_arm(arm.index(), |channel, _, _| channel.is_moving()).unwrap_or(false)
    }

    /// Redefine the count (arm at rest).
    pub fn set_position_steps(&mut self, arm: Arm, steps: i32) {
        with_arm(arm.index(), |channel, _, _| {
            channel.set_position(steps);
            if arm == Arm::Detector {
                DETECTOR_STEPS.store(steps, Ordering::Relaxed);
            }
        });
    }

    /// Enable (EN low) or disable (EN high) `arm`'s driver. A profile started later enables
    /// it again (`StepChannel`'s start).
    pub fn set_driver_enabled(&mut self, arm: Arm, enabled: bool) {
        with_arm(arm.index(), |_, timer, _| {
            // TMC2209 EN is active low.
            timer.en.set_level(Level::from(!enabled));
        });
    }

    /// The late interrupt of `arm` since the last call, if any.
    pub fn take_fault(&mut self, arm: Arm) -> Option<StepFault> {
        with_arm(arm.index(), |_, _, fault| fault.take()).flatten()
    }
}
