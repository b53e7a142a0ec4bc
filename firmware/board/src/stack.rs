//! The stack's high-water mark, for the self-test. cortex-m-rt's `paint-stack` fills the
//! stack region (memory.x: `_stack_end` up to `_stack_start`, below the statics) with
//! [`cortex_m_rt::STACK_PAINT_VALUE`] at reset; the lowest word no longer holding it is as
//! deep as the stack has been. A frame that stored the paint's own value at its deepest
//! word would hide a word or two: the figure is an estimate from below, which is why the
//! self-test's limit keeps a quarter of the stack in reserve.

use core::ptr::{addr_of, read_volatile};

unsafe extern "C" {
    /// The stack's floor and top (memory.x).
    static _stack_end: u32;
    static _stack_start: u32;
}

/// The deepest the stack has been since reset, and its size, bytes.
pub fn use_bytes() -> (u32, u32) {
    // Linker symbols: only their addresses are used (`addr_of!` reads nothing).
    let (floor, top) = (addr_of!(_stack_end) as u32, addr_of!(_stack_start) as u32);
    let mut word = floor;
    // SAFETY: word-aligned reads inside the stack region, from its floor up to the first
    // word that does not hold the paint, long before the live frames.
    while word < top
        && unsafe { read_volatile(word as *const u32) } == cortex_m_rt::STACK_PAINT_VALUE
    {
        word += 4;
    }
    (top - word, top - floor)
}
