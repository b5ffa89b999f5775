//! The STM32F4's flash access control register (`FLASH_ACR`, RM0383 section 3.8.1): what
//! the Black Pill writes to it at boot and after every flash write or erase, as values, so
//! that the host tests the sequence the board runs.
//!
//! At 96 MHz the flash needs wait states, and without the ART accelerator (prefetch,
//! instruction cache, data cache) every branch and every constant read from flash pays them:
//! the force tick, counted in instructions under QEMU, would take far longer than its count
//! on the chip. embassy-stm32's clock setup writes `FLASH_ACR` with the latency alone, which
//! clears `PRFTEN`, `ICEN` and `DCEN`, and nothing in embassy sets them again; the board
//! does, with [`cache_restart`], right after embassy's init.
//!
//! The caches hold flash contents: after a sector erase or a program the data cache may
//! still hold the bytes from before (the configuration log reads a slot blank, programs it,
//! then reads it back), so the board restarts the caches after every write and erase too.
//! A cache may be reset only while it is disabled (`ICRST`, `DCRST`: "can be written only
//! when the cache is disabled"), so the sequence is: caches off, reset, reset released,
//! caches (and prefetch) on, with the latency untouched throughout.

/// `LATENCY`: wait states (bits 3:0).
pub const LATENCY_MASK: u32 = 0xF;
/// Prefetch enable.
pub const PRFTEN: u32 = 1 << 8;
/// Instruction cache enable.
pub const ICEN: u32 = 1 << 9;
/// Data cache enable.
pub const DCEN: u32 = 1 << 10;
/// Instruction cache reset (only while `ICEN` is clear).
pub const ICRST: u32 = 1 << 11;
/// Data cache reset (only while `DCEN` is clear).
pub const DCRST: u32 = 1 << 12;
/// Prefetch and both caches: the ART accelerator on.
pub const ACCELERATED: u32 = PRFTEN | ICEN | DCEN;

/// The values to write to `FLASH_ACR`, in order, starting from its current value `acr`:
/// both caches and prefetch off, both caches reset, the reset released, then prefetch and
/// both caches on. Every other bit (the latency) is kept as it was.
pub const fn cache_restart(acr: u32) -> [u32; 4] {
    let keep = acr & !(ACCELERATED | ICRST | DCRST);
    [keep, keep | ICRST | DCRST, keep, keep | ACCELERATED]
}

/// Whether `acr` has prefetch and both caches on and no cache held in reset.
pub const fn is_accelerated(acr: u32) -> bool {
    acr & (ACCELERATED | ICRST | DCRST) == ACCELERATED
}
