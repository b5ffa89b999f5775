//! The thread-mode executor of every board: embassy's raw executor with our own `__pender`,
//! sleeping with WFI while there is nothing to do.
//!
//! QEMU treats WFE as a yield, so embassy's stock thread executor (SEV/WFE) busy-spins
//! while idle; WFI really sleeps until an interrupt, and under `-icount ...,sleep=off` lets
//! the virtual clock jump straight to the next timer event. On the STM32 WFI sleeps the
//! core until the next interrupt (USB, timers) just the same.

use core::sync::atomic::{AtomicBool, Ordering};

use embassy_executor::{raw, Spawner};

/// Set by the pender: the executor has work.
static PENDING: AtomicBool = AtomicBool::new(true);

/// Called by embassy (from any context) when a task was woken.
#[unsafe(export_name = "__pender")]
fn pender(_context: *mut ()) {
    // Only one executor exists: the context is not needed. If the pender runs in an
    // interrupt, returning from it ends the WFI below; in thread mode the flag is seen
    // before the next WFI.
    PENDING.store(true, Ordering::SeqCst);
}

/// Runs the executor forever after `init` has spawned the tasks.
pub fn run(init: impl FnOnce(Spawner)) -> ! {
    static mut EXECUTOR: Option<raw::Executor> = None;
    // SAFETY: `run` is called once, from `main`; the executor lives for the program.
    let executor: &'static raw::Executor = unsafe {
        let slot = &mut *core::ptr::addr_of_mut!(EXECUTOR);
        slot.insert(raw::Executor::new(core::ptr::null_mut()))
    };
    init(executor.spawner());
    loop {
        if PENDING.swap(false, Ordering::SeqCst) {
            // SAFETY: poll is never called re-entrantly: only this loop calls it.
            unsafe { executor.poll() };
        }
        // Sleep unless work arrived meanwhile. With interrupts masked, a pending interrupt
        // still ends WFI, and it runs when they are unmasked again, so no wake-up is lost.
        cortex_m::interrupt::disable();
        if !PENDING.load(Ordering::SeqCst) {
            cortex_m::asm::wfi();
        }
        // SAFETY: re-enables what was disabled just above.
        unsafe { cortex_m::interrupt::enable() };
    }
}
