//! The firmware's own faults: the order in which a fault handler makes every output safe,
//! what it tells the next boot, and how the next boot tells why it restarted.
//!
//! KLIPPER'S RULE: one safe stop, outputs first. A panic or a processor fault cannot trust
//! the program's state, so its handler ([`make_safe`]) does nothing before it has stopped
//! both step timers, disabled both drivers and switched the lamp off, by plain register
//! writes ([`SafeOutputs`]); then it logs, writes a [`FaultRecord`] into RAM that the
//! startup code does not clear, and resets the MCU. The next boot reads the record with the
//! reset flags ([`reset_cause`]): the device is then `Stopped` with the reason in
//! `Status::fault`, arms not homed, and the handshake announces it
//! (`DeviceInfo::reset_cause`), so the host hears why the instrument restarted.
//!
//! The faults that leave the program's state intact (a late step interrupt, a detector
//! overrun, a driver fault, a lost heartbeat) take the device's own fail-safe stop instead
//! (`Device::fail_safe_stop`): a ramped stop, no reset.

use protocol::{DeviceError, ErrorCode, ResetCause, ResetCounts};

/// The outputs a fault handler makes safe, each by a write that needs nothing else to
/// work (no lock, no allocation, no other peripheral).
pub trait SafeOutputs {
    /// Stop both step timers now, STEP low.
    fn stop_step_timers(&mut self);
    /// Disable both motor drivers (EN inactive): the arms hold no torque but get no steps.
    fn disable_drivers(&mut self);
    /// Switch the lamp off.
    fn lamp_off(&mut self);
}

/// The first thing a fault handler does: every output safe, in this order (the pulses end
/// first, so no step reaches a driver being disabled; the lamp last, it moves nothing).
pub fn make_safe(outputs: &mut impl SafeOutputs) {
    outputs.stop_step_timers();
    outputs.disable_drivers();
    outputs.lamp_off();
}

/// Marks a [`FaultRecord`] as written by a fault handler ("gonF").
pub const MAGIC: u32 = 0x676f_6e46;

/// What a fault handler leaves in no-init RAM for the next boot: four words, the magic,
/// the code, the detail and a check word, so that RAM that merely holds old or random
/// content (power-up) is never taken for a record.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FaultRecord(pub [u32; 4]);

const fn check_word(code: u32, detail: u32) -> u32 {
    // Any mix that a cleared or random RAM word does not match by chance (2^-32 a word).
    (MAGIC ^ code.rotate_left(7) ^ detail.rotate_left(19)).wrapping_mul(0x9e37_79b1) ^ 0x5a5a_a5a5
}

impl FaultRecord {
    /// The record of `error`.
    pub const fn new(error: DeviceError) -> FaultRecord {
        let code = error.code.code() as u32;
        let detail = error.detail as u32;
        FaultRecord([MAGIC, code, detail, check_word(code, detail)])
    }

    /// No record (what a boot leaves after reading one).
    pub const CLEARED: FaultRecord = FaultRecord([0; 4]);

    /// The fault, if these words are a record.
    pub fn error(&self) -> Option<DeviceError> {
        let [magic, code, detail, check] = self.0;
        if magic != MAGIC || check != check_word(code, detail) || code > u32::from(u16::MAX) {
            return None;
        }
        Some(DeviceError::with_detail(
            ErrorCode::from(code as u16),
            detail as i32,
        ))
    }
}

/// The reset flags of RCC_CSR (STM32F4), as the board reads them at boot.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ResetFlags {
    /// POR/PDR or BOR: the supply was off or low (RAM content is not to be trusted).
    pub power: bool,
    /// The reset pin (also set with every internal reset: the MCU drives its own pin).
    pub pin: bool,
    /// A software reset (SYSRESETREQ: the fault handler's, or a debugger's).
    pub software: bool,
    /// The independent or the window watchdog.
    pub watchdog: bool,
}

/// Why the MCU restarted, from the reset flags and the fault record found in RAM.
///
/// Power first (a record that survived a power cycle is not this boot's news); then a
/// record (written only by a fault handler just before its reset, and cleared by every
/// boot, so it is always about the reset that just happened, whatever flag that reset
/// set: a watchdog that fired in a slow handler included); then the watchdog; then a
/// software reset without a record (a debugger's); else the reset pin.
pub fn reset_cause(flags: ResetFlags, record: &FaultRecord) -> ResetCause {
    if flags.power {
        return ResetCause::PowerOn;
    }
    if let Some(error) = record.error() {
        return ResetCause::Fault(error);
    }
    if flags.watchdog {
        ResetCause::Watchdog
    } else if flags.software {
        ResetCause::Software
    } else if flags.pin {
        ResetCause::ResetPin
    } else {
        // No flag at all: a debugger's core-only reset; nothing went wrong.
        ResetCause::Software
    }
}

/// The error of a panic at source line `line`.
pub const fn panic_error(line: u32) -> DeviceError {
    DeviceError::with_detail(ErrorCode::Panic, line as i32)
}

/// The error of a processor fault: a stack overflow when the stack pointer at the fault
/// had run below `stack_limit` (the stack's lowest address, the end of RAM with the flipped
/// layout: the exception frame could not be stacked), otherwise a processor fault at the
/// stacked program counter `pc` (0 when the frame could not be read).
pub const fn processor_fault_error(stack_pointer: u32, stack_limit: u32, pc: u32) -> DeviceError {
    // The frame is 8 words: stacking it needs 32 bytes above the limit.
    if stack_pointer < stack_limit.saturating_add(32) {
        DeviceError::new(ErrorCode::StackOverflow)
    } else {
        DeviceError::with_detail(ErrorCode::ProcessorFault, pc as i32)
    }
}

/// Marks a [`ResetHistory`] ("gonR").
const HISTORY_MAGIC: u32 = 0x676f_6e52;

/// The resets since power-on, by cause, kept by the board in no-init RAM next to the
/// [`FaultRecord`]: four words, the magic, two words of counts and a check word, so that
/// RAM holding old or random content (after power-up) counts from zero. What the
/// self-test reports as `resets_since_power_on`: one watchdog or fault reset is a firmware
/// that hung or broke since the instrument was switched on, which the current reset cause
/// alone hides once anything resets it again.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ResetHistory(pub [u32; 4]);

impl ResetHistory {
    fn of(counts: ResetCounts) -> ResetHistory {
        let high = u32::from(counts.watchdog) << 16 | u32::from(counts.fault);
        let low = u32::from(counts.pin) << 16 | u32::from(counts.software);
        ResetHistory([HISTORY_MAGIC, high, low, history_check(high, low)])
    }

    /// The counts, if these words are a history.
    pub fn counts(&self) -> Option<ResetCounts> {
        let [magic, high, low, check] = self.0;
        (magic == HISTORY_MAGIC && check == history_check(high, low)).then_some(ResetCounts {
            watchdog: (high >> 16) as u16,
            fault: high as u16,
            pin: (low >> 16) as u16,
            software: low as u16,
        })
    }

    /// The history after a reset of `cause`, from what RAM held: a power-on (or RAM that
    /// holds no history: the first boot after power-up or flashing) starts from zero; any
    /// other reset adds one to its cause (saturating).
    pub fn after_reset(previous: &ResetHistory, cause: ResetCause) -> ResetHistory {
        let mut counts = match cause {
            ResetCause::PowerOn => ResetCounts::default(),
            _ => previous.counts().unwrap_or_default(),
        };
        let counter = match cause {
            ResetCause::PowerOn => None,
            ResetCause::Watchdog => Some(&mut counts.watchdog),
            ResetCause::Fault(_) => Some(&mut counts.fault),
            ResetCause::ResetPin => Some(&mut counts.pin),
            ResetCause::Software => Some(&mut counts.software),
        };
        if let Some(counter) = counter {
            *counter = counter.saturating_add(1);
        }
        ResetHistory::of(counts)
    }
}

const fn history_check(high: u32, low: u32) -> u32 {
    (HISTORY_MAGIC ^ high.rotate_left(11) ^ low.rotate_left(23)).wrapping_mul(0x85eb_ca6b)
        ^ 0xa5a5_5a5a
}
