//! How deep the stack has gone, measured on the running device.
//!
//! cortex-m-rt paints the whole stack region (from the end of the statics, `_stack_end`, up
//! to the initial stack pointer, `_stack_start`) with [`STACK_PAINT_VALUE`] at reset, before
//! `main` (its `paint-stack` feature). Whatever the program and its interrupts have pushed
//! since has scrubbed the paint off: the high-water mark is the distance from the top of the
//! stack to the lowest word that is no longer paint. The supervisor looks once a second and
//! the board reports each new maximum (QEMU on stdout, `STACK high_water_bytes=N`, which the
//! `hil` stack test reads; the Black Pill in its defmt log). The images' RAM budget counts the
//! stack reserve (`hil::firmware::Board::STACK_RESERVE`) justified by these readings.

use core::sync::atomic::{AtomicU32, Ordering};

use cortex_m_rt::STACK_PAINT_VALUE;

/// Only this much below the stack's top is looked at (the whole RAM budget: the scan reads
/// every word of it from the bottom up, so it is kept short); a stack deeper than this
/// reads as this deep.
pub const WATCHED: usize = 32 * 1024;

/// The deepest reading so far (bytes).
static HIGH_WATER: AtomicU32 = AtomicU32::new(0);

extern "C" {
    // From cortex-m-rt's linker script: the initial stack pointer (the stack's top) and
    // the lowest address the stack may grow to (the end of the statics).
    static _stack_start: u32;
    static _stack_end: u32;
}

/// Bytes of stack used at most since reset (saturating at [`WATCHED`]).
pub fn high_water() -> usize {
    // Only the symbols' addresses are taken (no read: safe).
    let top = core::ptr::addr_of!(_stack_start) as usize;
    let end = core::ptr::addr_of!(_stack_end) as usize;
    let mut p = top.saturating_sub(WATCHED).max(end).next_multiple_of(4);
    while p < top {
        // SAFETY: a word-aligned address inside the RAM the stack region spans; reading it
        // races with nothing that matters (a word below the stack pointer being written by
        // an interrupt at this moment reads as used either way).
        if unsafe { core::ptr::read_volatile(p as *const u32) } != STACK_PAINT_VALUE {
            break;
        }
        p += 4;
    }
    top - p
}

/// Reads the high-water mark and returns it if it is deeper than any reading before.
pub fn new_high_water() -> Option<usize> {
    let used = high_water();
    let prev = HIGH_WATER.fetch_max(used as u32, Ordering::Relaxed);
    (used as u32 > prev).then_some(used)
}
