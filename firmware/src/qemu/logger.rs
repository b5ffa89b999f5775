//! defmt on QEMU: frames go to the host's stderr through semihosting.
//!
//! The stream is defmt's standard rzCOBS encoding; decode it with
//! `defmt-print -e target/thumbv7em-none-eabihf/release/maobi-fw < stderr.bin`. Text that the
//! runner must read (bench results, fatal errors) goes to stdout as plain text instead (see
//! [`super::semihosting`]). A real board would use RTT here.

use core::sync::atomic::{AtomicBool, Ordering};

#[defmt::global_logger]
struct SemihostingLogger;

static TAKEN: AtomicBool = AtomicBool::new(false);
static mut RESTORE: critical_section::RestoreState = critical_section::RestoreState::invalid();
static mut ENCODER: defmt::Encoder = defmt::Encoder::new();

// SAFETY (all four functions): defmt calls acquire/release in pairs; between them this
// context holds a critical section, so the statics have a single user.
unsafe impl defmt::Logger for SemihostingLogger {
    fn acquire() {
        let restore = unsafe { critical_section::acquire() };
        if TAKEN.swap(true, Ordering::Relaxed) {
            panic!("defmt logger taken reentrantly");
        }
        unsafe {
            RESTORE = restore;
            (*core::ptr::addr_of_mut!(ENCODER)).start_frame(super::semihosting::stderr_bytes);
        }
    }

    unsafe fn flush() {}

    unsafe fn release() {
        unsafe {
            (*core::ptr::addr_of_mut!(ENCODER)).end_frame(super::semihosting::stderr_bytes);
        }
        TAKEN.store(false, Ordering::Relaxed);
        unsafe { critical_section::release(RESTORE) };
    }

    unsafe fn write(bytes: &[u8]) {
        unsafe {
            (*core::ptr::addr_of_mut!(ENCODER)).write(bytes, super::semihosting::stderr_bytes);
        }
    }
}

defmt::timestamp!("{=u32}", crate::app::TICKS.load(Ordering::Relaxed));
