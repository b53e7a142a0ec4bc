//! The stack's high-water mark, for the self-test: the stack region (memory.x, below the
//! statics) is painted with a pattern at boot, and the lowest word no longer holding it is
//! as deep as the stack has been. An exception frame that wrote the pattern's own value
//! would hide a word or two; a high-water mark is an estimate from below, which is why the
//! self-test's limit keeps a quarter of the stack in reserve.

use core::ptr::{addr_of, read_volatile, write_volatile};

/// What an unused stack word holds.
const PAINT: u32 = 0xACCE_55ED;
/// Left unpainted below the stack pointer at the paint: the painting function's own frame
/// and the calls it makes, bytes.
const MARGIN: u32 = 256;

unsafe extern "C" {
    /// The stack's floor and top (memory.x).
    static _stack_end: u32;
    static _stack_start: u32;
}

/// A linker symbol: only its address is used (`addr_of!` reads nothing).
fn floor() -> u32 {
    addr_of!(_stack_end) as u32
}

fn top() -> u32 {
    addr_of!(_stack_start) as u32
}

/// Paint the stack below the current stack pointer. First thing in `main`.
pub fn paint() {
    let sp = cortex_m::register::msp::read();
    let mut word = floor();
    while word + MARGIN < sp {
        // SAFETY: between the stack's floor and below the stack pointer by the margin: stack
        // memory nothing uses yet (the stack grows down towards it), word-aligned.
        unsafe { write_volatile(word as *mut u32, PAINT) };
        word += 4;
    }
}

/// The deepest the stack has been since the paint, and its size, bytes.
pub fn use_bytes() -> (u32, u32) {
    let mut word = floor();
    // SAFETY: reads of stack memory below the stack pointer (the scan stops at the first
    // word that does not hold the paint, long before the live frames), word-aligned.
    while word < top() && unsafe { read_volatile(word as *const u32) } == PAINT {
        word += 4;
    }
    (top() - word, top() - floor())
}
