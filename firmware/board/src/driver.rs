//! The stepper driver modules this board drives: a build-time choice, one cargo feature per
//! kind (`driver-tmc2209`, the default, or `driver-drv8825`), because what their pins mean
//! differs where a wrong guess is unsafe:
//!
//! | | TMC2209 (default) | DRV8825 |
//! |---|---|---|
//! | Fault output on DIAG_I/DIAG_R (PA2/PA3) | DIAG, push-pull, **high** = fault; internal pull-down (a missing module reads healthy) | nFAULT, open-drain, **low** = fault; internal pull-up (a missing module reads healthy) |
//! | Fault cleared by | EN high (the `Home`'s EN cycle, `firmware::device`) | thermal: by itself; over-current: latched until nRESET or power, which this board does not drive, so a `Home` stays refused (`HardwareFault`) until the motor supply is cycled |
//! | STEP high time, minimum | 100 ns | 1.9 µs |
//! | STEP high time, this build | 2 µs | 3 µs (2 µs left 0.1 µs of margin) |
//! | EN | EN, active low | nENBL, active low |
//! | 1/16 microstepping (0.0125°/step with the gearing) | MS1 = MS2 = high | MODE2 high, MODE1 = MODE0 low |
//!
//! Not supported: the A4988 and other modules without a fault output. The fail-safe stop on
//! a driver fault and the self-test's driver check would be blind with them (a pin that
//! never reads a fault is a check that cannot fail), so no feature pretends to drive them.
//!
//! Datasheets: TMC2209 (Trinamic/ADI, rev 1.09) §2.2, §5; DRV8825 (TI, SLVSA73F) 6.6, 7.3.9,
//! 7.3.11. Neither module has been wired to this board yet.

use embassy_stm32::gpio::Pull;

#[cfg(all(feature = "driver-tmc2209", feature = "driver-drv8825"))]
compile_error!(
    "features `driver-tmc2209` and `driver-drv8825` are exclusive: pick the driver modules on your board"
);
#[cfg(not(any(feature = "driver-tmc2209", feature = "driver-drv8825")))]
compile_error!(
    "pick the driver modules: feature `driver-tmc2209` (the default) or `driver-drv8825` \
     (`--no-default-features --features hse-25mhz,driver-drv8825`)"
);

/// What the board needs to know of its driver modules.
pub struct DriverKind {
    /// For the boot log.
    pub name: &'static str,
    /// The fault output reads a fault when high (`false`: when low).
    pub fault_active_high: bool,
    /// The fault input's pull: the idle (healthy) level, so that a missing module or a
    /// broken wire reads healthy rather than faulted (the self-test's driver check and a
    /// first motion tell them apart).
    pub fault_pull: Pull,
    /// STEP high time, timer ticks (µs).
    pub step_pulse_ticks: u16,
}

/// The driver modules of this build.
#[cfg(feature = "driver-tmc2209")]
pub const DRIVER: DriverKind = DriverKind {
    name: "TMC2209",
    fault_active_high: true,
    fault_pull: Pull::Down,
    step_pulse_ticks: firmware::stepgen::PULSE_TICKS,
};

/// The driver modules of this build.
#[cfg(all(feature = "driver-drv8825", not(feature = "driver-tmc2209")))]
pub const DRIVER: DriverKind = DriverKind {
    name: "DRV8825",
    fault_active_high: false,
    fault_pull: Pull::Up,
    step_pulse_ticks: 3,
};

// The pulse must end well inside the shortest segment the step generator makes.
const _: () = assert!((DRIVER.step_pulse_ticks as u32) * 4 <= firmware::stepgen::MIN_SEGMENT_TICKS);

/// Whether the fault input's level means a fault.
pub fn is_fault(level_high: bool) -> bool {
    level_high == DRIVER.fault_active_high
}
