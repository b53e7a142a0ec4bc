//! The small hardware traits the firmware library drives. The board implements them with
//! its peripherals (timers, GPIO, ADC); the simulator and the tests with models on virtual
//! time. Nothing here decides anything: the traits only act and report.

use crate::motion::MoveProfile;
use crate::sampling::SampleLoss;

/// One of the two arms.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Arm {
    /// The source arm (θi).
    Source,
    /// The detector arm (θr).
    Detector,
}

impl Arm {
    /// Both arms, source first.
    pub const BOTH: [Arm; 2] = [Arm::Source, Arm::Detector];

    /// 0 for the source arm, 1 for the detector arm (the `detail` of arm errors).
    pub const fn index(self) -> usize {
        match self {
            Arm::Source => 0,
            Arm::Detector => 1,
        }
    }
}

/// Two stepper-driven arms with a home switch each.
///
/// Positions are microstep counts kept by the step generator (one count per step pulse
/// issued, signed by direction); the library defines their zero by homing.
pub trait Arms {
    /// Start executing `profile` now, replacing whatever the arm was running; the arm is at
    /// `profile.start_steps()`. A board runs it from a hardware timer: step `k` is issued
    /// at `profile.step_time_us(k)` after the start, so the rate holds whatever the CPU
    /// does. Returns at once.
    fn run_profile(&mut self, arm: Arm, profile: &MoveProfile);
    /// The arm's step count now.
    fn position_steps(&self, arm: Arm) -> i32;
    /// Whether the arm is still executing a profile.
    fn is_moving(&self, arm: Arm) -> bool;
    /// Redefine the step count of the arm's current position (homing; arm at rest).
    fn set_position_steps(&mut self, arm: Arm, steps: i32);
    /// Whether the arm's home switch is pressed.
    fn home_switch_pressed(&self, arm: Arm) -> bool;
    /// Whether the arm's stepper driver reports a fault (over-temperature, short, …).
    fn driver_fault(&self, arm: Arm) -> bool;
    /// Enable or disable the arm's stepper driver (EN). A disabled driver holds no torque
    /// and takes no steps; a TMC2209 clears its latched fault (DIAG) only while disabled.
    /// A profile with steps enables the driver too (the board's step generator does it at
    /// the profile's start), so the library disables a driver only where no profile
    /// follows until it enables it again: a faulted arm after the fail-safe stop, and
    /// during a `Home`'s clearing of a fault ([`crate::device`]).
    fn set_driver_enabled(&mut self, arm: Arm, enabled: bool);
    /// Whether the arm's step interrupt ran too late since the last call (the timer may
    /// have issued a step nobody counted; [`crate::stepgen`]); cleared by the call.
    fn take_step_fault(&mut self, arm: Arm) -> bool;
    /// Issue `profile`'s step pulses with the driver left disabled (EN high: no torque, the
    /// arm does not move) and count them as [`Arms::run_profile`] does: the self-test's
    /// pulse check ([`crate::selftest`]). The arm is at rest and its driver disabled.
    fn run_pulse_check(&mut self, arm: Arm, profile: &MoveProfile);
}

/// The clocks a board measured at boot ([`crate::clock`]): what it was built for and what
/// it found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MeasuredClocks {
    /// The crystal the build expects, Hz.
    pub hse_expected_hz: u32,
    /// The crystal measured against HSI, Hz (`None`: not measured).
    pub hse_measured_hz: Option<u32>,
    /// The core clock the build sets up, Hz.
    pub sysclk_expected_hz: u32,
    /// The core clock measured against the crystal, Hz (`None`: not measured).
    pub sysclk_measured_hz: Option<u32>,
}

/// How much of its stack the firmware has used since boot.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StackUse {
    /// The high-water mark, bytes (from the painted stack).
    pub used_bytes: u32,
    /// The stack's size, bytes.
    pub size_bytes: u32,
}

/// What only the board can measure about itself, read by the self-test
/// ([`crate::selftest`]); `None` where this hardware cannot measure it.
pub trait Diagnostics {
    /// The clocks as measured at boot.
    fn clocks(&self) -> MeasuredClocks;
    /// The latest any step interrupt ran after its segment began, since boot, µs.
    fn worst_step_late_us(&self) -> u32;
    /// The longest section with interrupts off since boot, µs.
    fn longest_interrupts_off_us(&self) -> Option<u32>;
    /// The stack's high-water mark since boot.
    fn stack_use(&self) -> Option<StackUse>;
    /// The range the amplifier's select lines read back (one-hot decoded; 255 when they are
    /// not one-hot).
    fn range_read_back(&self) -> Option<u8>;
    /// The resets since power-on by cause ([`crate::fault::ResetHistory`]).
    fn resets_since_power_on(&self) -> Option<protocol::ResetCounts>;
}

/// One detector sample: one block of oversampled ADC conversions
/// ([`crate::config::InstrumentConfig::detector_block_us`] long), and where the detector
/// arm was when it ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Sample {
    /// ADC counts (dark offset included).
    pub counts: u32,
    /// The detector arm's step count at the end of the block (the board's decimation
    /// interrupt reads the step generator's count when it closes the block): a sweep's
    /// bins take their angles from these.
    pub detector_steps: i32,
}

/// The photodiode, its transimpedance ranges and the ADC.
pub trait Detector {
    /// Switch the amplifier to `range` (index into the configured ranges, most sensitive
    /// first). Samples taken while it settles are discarded by the library.
    fn select_range(&mut self, range: u8);
    /// Hand every sample taken since the last call to `sink`, oldest first, each stamped
    /// with the detector arm's step count at its end; `Err` when samples were lost or
    /// could have been mixed since the last call (the overrun rule of [`crate::sampling`]).
    fn drain_samples(&mut self, sink: &mut dyn FnMut(Sample)) -> Result<(), SampleLoss>;
    /// An overrun of the ADC path itself (the ADC, or its DMA lapping the decimation)
    /// since the last call, whether or not samples were drained; cleared by the call.
    fn take_sample_fault(&mut self) -> Option<SampleLoss>;
}

/// The light source.
pub trait Lamp {
    /// Switch the lamp.
    fn set_lamp(&mut self, on: bool);
}

/// Everything the device drives.
pub trait Hardware: Arms + Detector + Lamp + Diagnostics {}

impl<T: Arms + Detector + Lamp + Diagnostics> Hardware for T {}

/// Why the MCU last came out of reset: the board reads RCC_CSR and the fault record that
/// its fail-safe reset left in RAM ([`crate::fault`]); announced in the handshake.
pub use protocol::ResetCause;
