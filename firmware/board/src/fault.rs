//! One safe stop for every fault the program cannot recover from (Klipper's rule): the
//! panic handler, the HardFault handler and the handler of an unexpected interrupt first
//! stop both step timers, disable both drivers (EN high) and switch the lamp off, by plain
//! register writes ([`firmware::fault::make_safe`]); then they write the reason into RAM
//! that the startup code leaves alone, log it (defmt), and reset the MCU. The next boot
//! reads the reason with the reset flags ([`reset_cause`]) and the device reports it: in
//! the handshake (`DeviceInfo::reset_cause`) and as the fault of its `Stopped` state.
//!
//! A stack overflow is one of these: the stack sits at the bottom of the SRAM
//! (`memory.x`), so an overflow runs off the start of the SRAM and faults. The HardFault
//! entry, in assembly, moves the stack pointer back to the top of the stack region before
//! anything else runs (the handler's own pushes would otherwise fault again and lock the
//! core up, with the arms stepping until the watchdog fires); the handler then tells the
//! overflow (the stack pointer was at the floor) from another fault (the stacked PC).
//!
//! The order is the point: the record is written before the log, so a log that blocks (a
//! probe holding RTT in blocking mode) still leaves the reason for the watchdog's reset.

use core::mem::MaybeUninit;
use core::sync::atomic::{AtomicBool, AtomicU16, Ordering};

use cortex_m::peripheral::SCB;
use defmt::error;
use embassy_stm32::pac;
use embassy_stm32::pac::timer::vals;
use firmware::ResetCause;
use firmware::fault::{
    FaultRecord, ResetFlags, ResetHistory, SafeOutputs, make_safe, panic_error,
    processor_fault_error,
};
use protocol::{DeviceError, ResetCounts};

/// The record for the next boot: in `.uninit`, which cortex-m-rt neither zeroes nor
/// initialises, so it survives the reset (not a power cycle: the check word and the
/// power-on flag take care of that).
#[unsafe(link_section = ".uninit.gonio_fault_record")]
static mut RECORD: MaybeUninit<[u32; 4]> = MaybeUninit::uninit();

fn write_record(record: FaultRecord) {
    // SAFETY: the handlers run with interrupts off and the boot before anything else:
    // nothing else touches RECORD. Volatile: it must reach RAM before the reset.
    unsafe {
        core::ptr::write_volatile(core::ptr::addr_of_mut!(RECORD).cast::<[u32; 4]>(), record.0)
    }
}

/// The record the last fault left (or RAM content that is none), cleared for the next time.
fn take_record() -> FaultRecord {
    // SAFETY: called once at boot, before interrupts; any bit pattern is a valid [u32; 4].
    unsafe {
        let slot = core::ptr::addr_of_mut!(RECORD).cast::<[u32; 4]>();
        let words = core::ptr::read_volatile(slot);
        core::ptr::write_volatile(slot, FaultRecord::CLEARED.0);
        FaultRecord(words)
    }
}

/// Why the MCU came out of reset: RCC_CSR's flags (cleared for the next time) and the
/// record of a fault handler. Call first thing at boot.
pub fn reset_cause() -> ResetCause {
    let csr = pac::RCC.csr().read();
    pac::RCC.csr().modify(|w| w.set_rmvf(true));
    let flags = ResetFlags {
        power: csr.porrstf() || csr.borrstf(),
        pin: csr.padrstf(),
        software: csr.sftrstf(),
        watchdog: csr.wdgrstf() || csr.wwdgrstf(),
    };
    firmware::fault::reset_cause(flags, &take_record())
}

/// The resets since power-on (`firmware::fault::ResetHistory`): in `.uninit` like the
/// fault record, so it survives every reset but a power cycle.
#[unsafe(link_section = ".uninit.gonio_reset_history")]
static mut HISTORY: MaybeUninit<[u32; 4]> = MaybeUninit::uninit();

/// Count this boot's reset in the history and return the counts since power-on. Call once
/// at boot, after [`reset_cause`].
pub fn count_reset(cause: ResetCause) -> ResetCounts {
    // SAFETY: called once at boot, before interrupts; any bit pattern is a valid [u32; 4].
    let history = unsafe {
        let slot = core::ptr::addr_of_mut!(HISTORY).cast::<[u32; 4]>();
        let history =
            ResetHistory::after_reset(&ResetHistory(core::ptr::read_volatile(slot)), cause);
        core::ptr::write_volatile(slot, history.0);
        history
    };
    history.counts().unwrap_or_default()
}

/// An unset pin of [`SAFE_PINS`].
const UNSET: u16 = u16::MAX;
/// The EN pins of both drivers and the lamp pin, as `port << 8 | pin`, registered by
/// [`crate::pins`] when it sets them up (before that, they are inputs in their reset state
/// and the external pull-up / pull-down keep drivers and lamp off).
static SAFE_PINS: [AtomicU16; 3] = [const { AtomicU16::new(UNSET) }; 3];
const EN_I: usize = 0;
const EN_R: usize = 1;
const LAMP: usize = 2;

/// Register the pins the safe stop drives: `(port, pin)` of each driver's EN and the lamp.
pub fn register_safe_pins(en: [(u8, u8); 2], lamp: (u8, u8)) {
    for (slot, (port, pin)) in [(EN_I, en[0]), (EN_R, en[1]), (LAMP, lamp)] {
        SAFE_PINS[slot].store(u16::from(port) << 8 | u16::from(pin), Ordering::Relaxed);
    }
}

/// Drive a registered pin by its port's BSRR: one write, no lock, whatever state the
/// program is in.
fn drive(slot: usize, high: bool) {
    let packed = SAFE_PINS[slot].load(Ordering::Relaxed);
    if packed == UNSET {
        return;
    }
    let (port, pin) = (usize::from(packed >> 8), usize::from(packed & 0xff));
    // SAFETY: GPIOA.. GPIOH of the F411 are 0x400 apart from 0x4002_0000; the port number
    // is embassy's for a pin of this chip.
    let gpio = unsafe { pac::gpio::Gpio::from_ptr((0x4002_0000 + 0x400 * port) as *mut ()) };
    gpio.bsrr().write(|w| {
        if high {
            w.set_bs(pin, true)
        } else {
            w.set_br(pin, true)
        }
    });
}

/// The outputs, by register writes only.
struct BoardOutputs;

impl SafeOutputs for BoardOutputs {
    fn stop_step_timers(&mut self) {
        for index in 0..2 {
            let tim = crate::steppers::timer(index);
            // STEP low now (output compare forced inactive: not preloaded), counter stopped,
            // no more update interrupts.
            tim.ccmr_output(1)
                .modify(|w| w.set_ocm(0, vals::Ocm::FORCE_INACTIVE));
            tim.cr1().modify(|w| w.set_cen(false));
            tim.dier().modify(|w| w.set_uie(false));
        }
    }

    fn disable_drivers(&mut self) {
        // TMC2209 EN is active low.
        drive(EN_I, true);
        drive(EN_R, true);
    }

    fn lamp_off(&mut self) {
        drive(LAMP, false);
    }
}

/// Set by the first fault handler: a fault inside the handler (in its log) goes straight
/// to the reset, the record already written.
static HANDLING: AtomicBool = AtomicBool::new(false);

/// Outputs safe, record, log, reset.
fn stop_and_reset(error: DeviceError, log: impl FnOnce(DeviceError)) -> ! {
    cortex_m::interrupt::disable();
    make_safe(&mut BoardOutputs);
    if !HANDLING.swap(true, Ordering::Relaxed) {
        write_record(FaultRecord::new(error));
        log(error);
    }
    SCB::sys_reset()
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    let (file, line) = info
        .location()
        .map_or(("?", 0), |at| (at.file(), at.line()));
    // The message is not formatted: that would link core::fmt (22 KiB with floats).
    stop_and_reset(panic_error(line), |_| {
        error!(
            "panic at {=str}:{=u32}: outputs safe, resetting",
            file, line
        )
    })
}

unsafe extern "C" {
    /// The stack's floor (memory.x): an exception frame below it could not be stacked.
    static _stack_end: u32;
    /// The end of the SRAM.
    static _ram_end: u32;
}

// The HardFault entry (hard_fault_entry.s, shared with the on-target tests): pick the
// stack the fault was on, move the stack pointer back into the stack region (a stack
// overflow left it below the SRAM; any push would fault again), then the handler, with
// the faulting stack pointer in r0. Nothing there uses the stack.
core::arch::global_asm!(include_str!("hard_fault_entry.s"), handler = sym hard_fault);

/// The HardFault handler proper, on a fresh stack; `sp` is the stack pointer at the fault.
extern "C" fn hard_fault(sp: u32) -> ! {
    // Linker symbols: only their addresses are used.
    let (floor, end) = (
        core::ptr::addr_of!(_stack_end) as u32,
        core::ptr::addr_of!(_ram_end) as u32,
    );
    // The stacked PC is the 7th word of the frame, if the frame is in RAM.
    let pc = if sp >= floor.saturating_add(32) && sp.saturating_add(32) <= end {
        // SAFETY: inside the SRAM, 4-byte aligned (exception frames are).
        unsafe { core::ptr::read_volatile((sp + 24) as *const u32) }
    } else {
        0
    };
    let error = processor_fault_error(sp, floor, pc);
    stop_and_reset(error, |error| {
        error!(
            "processor fault (SP {=u32:#x}): {}; outputs safe, resetting",
            sp, error
        )
    })
}

/// An interrupt with no handler: the program is not what it thinks it is. The same safe
/// stop as a panic (recorded as a panic at this line), and the log only after it: a log
/// can block (a probe holding RTT in blocking mode) while the arms step on.
#[cortex_m_rt::exception]
unsafe fn DefaultHandler(irqn: i16) {
    stop_and_reset(panic_error(line!()), |_| {
        error!("unexpected interrupt {}: outputs safe, resetting", irqn)
    })
}
