//! The firmware library's scenarios and the fault handlers' paths, compiled for the
//! Cortex-M4 and run under QEMU (`qemu-system-arm -M mps2-an386 -cpu cortex-m4
//! -semihosting`): the code that ships, on the instruction set it ships on.
//!
//! The program goes through phases across real resets (SYSRESETREQ; QEMU keeps the RAM,
//! and cortex-m-rt leaves `.uninit` alone, as on the board), its progress in `PERSIST`:
//! 1. every scenario of `firmware::scenarios` (handshake, homing, a whole Strategy 1, the
//!    fail-safe paths), one line each with the digest of what the device sent (compared
//!    with the same scenarios on the host by `.ci/qemu-tests`); then the stack high-water
//!    mark (the stack is painted at reset: the deepest word no longer 0xCCCCCCCC);
//! 2. a deliberate panic (an index out of bounds) mid-move with the lamp on: the panic
//!    handler makes the fake hardware safe (`firmware::fault::make_safe`), writes the
//!    record, resets; after the reset the record must give the reset cause, the device
//!    must announce it at the handshake and be stopped, unhomed, lamp off;
//! 3. a stack overflow: the stack is at the bottom of RAM, so it runs off it and faults;
//!    the HardFault entry (the board's, `hard_fault_entry.s`) recovers a stack, the
//!    handler must classify it as a stack overflow, and the reason must survive the reset.
//!
//! Then `N passed, N failed`, and the exit status through semihosting.
#![no_std]
#![no_main]

mod isr_cost;

use core::mem::MaybeUninit;
use core::ptr::{addr_of, addr_of_mut};

use cortex_m::peripheral::SCB;
use cortex_m_rt::entry;
use cortex_m_semihosting::{debug, hprintln};
use firmware::fault::{
    FaultRecord, ResetFlags, make_safe, panic_error, processor_fault_error, reset_cause,
};
use firmware::hardware::ResetCause;
use firmware::scenarios::{self, Bench, SCENARIOS, hardware_is_safe};
use protocol::{Angle, DeviceError, ErrorCode, Geometry};

/// What survives the resets.
#[repr(C)]
struct Persist {
    magic: u32,
    phase: u32,
    passed: u32,
    failed: u32,
    stack_used: u32,
    /// The fake hardware was safe when the panic handler was done with it.
    safe: u32,
    /// The arms' true angles then, ticks.
    at: [i32; 2],
    record: [u32; 4],
}

const MAGIC: u32 = 0x6761_7267;
const SCENARIOS_PHASE: u32 = 0;
const PANIC_PHASE: u32 = 1;
const AFTER_PANIC: u32 = 2;
const OVERFLOW_PHASE: u32 = 3;
const AFTER_OVERFLOW: u32 = 4;

#[unsafe(link_section = ".uninit.persist")]
static mut PERSIST: MaybeUninit<Persist> = MaybeUninit::uninit();

/// The bench the panic interrupts (the panic handler makes its hardware safe).
static mut BENCH: MaybeUninit<Bench> = MaybeUninit::uninit();

fn persist() -> &'static mut Persist {
    // SAFETY: one thread, no interrupts; any bit pattern is a valid Persist (checked by
    // the magic before use).
    unsafe { &mut *addr_of_mut!(PERSIST).cast::<Persist>() }
}

unsafe extern "C" {
    static _stack_start: u32;
    static _stack_end: u32;
}

/// The deepest the stack has been since the reset painted it, bytes.
fn stack_used() -> u32 {
    let (floor, top) = (addr_of!(_stack_end) as u32, addr_of!(_stack_start) as u32);
    let mut at = floor;
    while at < top {
        // SAFETY: inside the stack region, aligned.
        if unsafe { core::ptr::read_volatile(at as *const u32) } != cortex_m_rt::STACK_PAINT_VALUE {
            break;
        }
        at += 4;
    }
    top - at
}

fn check(p: &mut Persist, name: &str, ok: bool, what: &str) {
    if ok {
        p.passed += 1;
        hprintln!("test {} ... ok", name);
    } else {
        p.failed += 1;
        hprintln!("test {} ... FAILED: {}", name, what);
    }
}

/// The line of the panic of phase 2: the index out of bounds four lines down.
const PANIC_LINE: u32 = line!() + 4;
#[inline(never)]
fn deliberate_panic(bench: &mut Bench) -> u64 {
    let index = core::hint::black_box(3 + bench.now_us() as usize % 2);
    [1u64, 2, 3][index]
}

/// Stack without end (not a tail call: the frame is used after the call).
#[inline(never)]
#[allow(unconditional_recursion)]
fn deeper(n: u32) -> u32 {
    let frame = core::hint::black_box([n; 32]);
    deeper(n + 1).wrapping_add(frame[n as usize % 32])
}

fn finish(p: &mut Persist) -> ! {
    hprintln!("stack high-water mark: {} bytes (scenarios)", p.stack_used);
    hprintln!("{} passed, {} failed", p.passed, p.failed);
    let ok = p.failed == 0;
    p.magic = 0;
    debug::exit(if ok {
        debug::EXIT_SUCCESS
    } else {
        debug::EXIT_FAILURE
    });
    loop {}
}

/// The reset flags a fault handler's own SYSRESETREQ leaves on the STM32 (QEMU's machine
/// has no RCC).
const HANDLER_RESET: ResetFlags = ResetFlags {
    power: false,
    pin: true,
    software: true,
    watchdog: false,
};

#[entry]
fn main() -> ! {
    let p = persist();
    if p.magic != MAGIC {
        *p = Persist {
            magic: MAGIC,
            phase: SCENARIOS_PHASE,
            passed: 0,
            failed: 0,
            stack_used: 0,
            safe: 0,
            at: [0; 2],
            record: [0; 4],
        };
    }
    match p.phase {
        SCENARIOS_PHASE => {
            hprintln!(
                "gonio target tests: {} scenarios, then a panic and a stack overflow, on the Cortex-M4",
                SCENARIOS.len()
            );
            for scenario in SCENARIOS {
                match (scenario.run)() {
                    Ok(digest) => {
                        p.passed += 1;
                        hprintln!("scenario {} ok digest {:08x}", scenario.name, digest);
                        hprintln!("  stack high-water so far: {} bytes", stack_used());
                    }
                    Err(failure) => {
                        p.failed += 1;
                        hprintln!(
                            "scenario {} FAILED: {} (scenarios.rs:{})",
                            scenario.name,
                            failure.what,
                            failure.line
                        );
                    }
                }
            }
            p.stack_used = stack_used();
            let mut core = cortex_m::Peripherals::take().expect("the core peripherals, once");
            let cost = isr_cost::measure(&mut core.SYST);
            hprintln!(
                "step generator: on_update at most {} instructions, {} taking over a profile, run_prepared at most {} (Start::prepare, outside the lock, {}) ({} updates, resolution {} instructions)",
                cost.on_update,
                cost.on_update_handover,
                cost.run_profile,
                cost.prepare,
                cost.updates,
                cost.resolution
            );
            check(
                p,
                "isr_cost_measured",
                cost.updates > 10_000 && cost.on_update > 0,
                "no updates measured, or SysTick did not count (QEMU without -icount?)",
            );
            p.phase = PANIC_PHASE;
            match scenarios::moving_with_lamp_on() {
                Ok(bench) => {
                    // SAFETY: written once, before the panic that reads it.
                    let bench = unsafe { (*addr_of_mut!(BENCH)).write(bench) };
                    let _ = deliberate_panic(bench);
                    check(
                        p,
                        "deliberate_panic",
                        false,
                        "the index out of bounds did not panic",
                    );
                }
                Err(failure) => check(p, "deliberate_panic", false, failure.what),
            }
            p.phase = OVERFLOW_PHASE;
            SCB::sys_reset()
        }
        AFTER_PANIC => {
            let record = FaultRecord(p.record);
            let expected = panic_error(PANIC_LINE);
            check(
                p,
                "panic_record",
                record.error() == Some(expected),
                "the record is not the panic's",
            );
            check(
                p,
                "panic_left_outputs_safe",
                p.safe == 1,
                "timers running, a driver enabled or the lamp on",
            );
            let cause = reset_cause(HANDLER_RESET, &record);
            let at = Geometry::new(Angle::from_ticks(p.at[0]), Angle::from_ticks(p.at[1]));
            let reported = scenarios::report_after_reset(at, cause, expected);
            check(
                p,
                "panic_reported_after_reset",
                reported.is_ok(),
                reported.err().map_or("", |f| f.what),
            );
            p.phase = OVERFLOW_PHASE;
            SCB::sys_reset()
        }
        OVERFLOW_PHASE => {
            let _ = core::hint::black_box(deeper(0));
            check(
                p,
                "stack_overflow",
                false,
                "the stack ran out without a fault",
            );
            finish(p)
        }
        AFTER_OVERFLOW => {
            let record = FaultRecord(p.record);
            let overflow = DeviceError::new(ErrorCode::StackOverflow);
            check(
                p,
                "stack_overflow_faults",
                record.error() == Some(overflow),
                "not recorded as a stack overflow",
            );
            check(
                p,
                "stack_overflow_reported_after_reset",
                reset_cause(HANDLER_RESET, &record) == ResetCause::Fault(overflow),
                "the reset cause",
            );
            finish(p)
        }
        _ => {
            check(p, "phases", false, "lost track of the phase");
            finish(p)
        }
    }
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    let p = persist();
    let line = info.location().map_or(0, |at| at.line());
    if p.magic == MAGIC && p.phase == PANIC_PHASE {
        // The board's handler, on the fake hardware: outputs first.
        // SAFETY: BENCH was written before the deliberate panic.
        let bench = unsafe { (*addr_of_mut!(BENCH)).assume_init_mut() };
        let later = bench.now_us() + 1000;
        let hardware = bench.hw_mut();
        make_safe(hardware);
        p.record = FaultRecord::new(panic_error(line)).0;
        // A millisecond later nothing may run any more.
        hardware.advance_to(later);
        let hardware = bench.hw_mut();
        p.safe = u32::from(hardware_is_safe(hardware));
        let at = hardware.true_geometry();
        p.at = [at.theta_i.ticks(), at.theta_r.ticks()];
        p.phase = AFTER_PANIC;
        hprintln!(
            "panicked at line {}: fake outputs made safe, resetting",
            line
        );
        SCB::sys_reset()
    }
    hprintln!("unexpected panic at line {}", line);
    p.failed += 1;
    finish(p)
}

// The board's HardFault entry: the stack pointer back into RAM before anything pushes.
core::arch::global_asm!(include_str!("../../board/src/hard_fault_entry.s"), handler = sym hard_fault);

extern "C" fn hard_fault(sp: u32) -> ! {
    let p = persist();
    let floor = addr_of!(_stack_end) as u32;
    let error = processor_fault_error(sp, floor, 0);
    if p.magic == MAGIC && p.phase == OVERFLOW_PHASE {
        p.record = FaultRecord::new(error).0;
        p.phase = AFTER_OVERFLOW;
        hprintln!(
            "processor fault with SP {:#010x} (stack floor {:#010x}): resetting",
            sp,
            floor
        );
        SCB::sys_reset()
    }
    hprintln!("unexpected processor fault, SP {:#010x}", sp);
    p.failed += 1;
    finish(p)
}
