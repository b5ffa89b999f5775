//! A one-slot, lock-free hand-off from the force loop (producer, highest priority) to a
//! thread-mode consumer: the producer fills the slot when the consumer requested it or when
//! a value falls due and the slot is free; the consumer takes. Neither side ever waits for
//! the other (a due value finding the slot full is dropped and counted by the producer).

use core::cell::UnsafeCell;
use core::sync::atomic::{AtomicU8, Ordering};

const IDLE: u8 = 0;
const REQUESTED: u8 = 1;
const FULL: u8 = 2;

pub struct Mailbox<T> {
    state: AtomicU8,
    slot: UnsafeCell<T>,
}

// SAFETY: the slot is written only by the producer while the state is REQUESTED and read
// only by the consumer while it is FULL; the state transitions (Release/Acquire) order the
// accesses, so the two sides never touch the slot at the same time.
unsafe impl<T: Send> Sync for Mailbox<T> {}

impl<T> Mailbox<T> {
    pub const fn new(init: T) -> Self {
        Mailbox {
            state: AtomicU8::new(IDLE),
            slot: UnsafeCell::new(init),
        }
    }

    #[cfg_attr(not(feature = "board-qemu"), allow(dead_code))] // QEMU's selftest asks
    /// Consumer: asks for a fill. False if a request or a value is already outstanding.
    pub fn request(&self) -> bool {
        self.state
            .compare_exchange(IDLE, REQUESTED, Ordering::AcqRel, Ordering::Acquire)
            .is_ok()
    }

    /// Producer: fills the slot if it was requested, or if `due` and the slot is free.
    /// Returns whether it filled it (false: not wanted, or the consumer still holds the
    /// last value).
    pub fn offer(&self, due: bool, f: impl FnOnce(&mut T)) -> bool {
        let s = self.state.load(Ordering::Acquire);
        if s == REQUESTED || (due && s == IDLE) {
            // SAFETY: not FULL: the consumer does not touch the slot, and only the producer
            // (this single context) fills it.
            f(unsafe { &mut *self.slot.get() });
            self.state.store(FULL, Ordering::Release);
            true
        } else {
            false
        }
    }

    /// Consumer: a filled value is waiting.
    pub fn is_full(&self) -> bool {
        self.state.load(Ordering::Acquire) == FULL
    }

    /// Consumer: reads the filled slot and frees it. None if not filled yet.
    pub fn take<R>(&self, f: impl FnOnce(&T) -> R) -> Option<R> {
        if self.state.load(Ordering::Acquire) != FULL {
            return None;
        }
        // SAFETY: FULL: the producer no longer touches the slot until the next request.
        let r = f(unsafe { &*self.slot.get() });
        self.state.store(IDLE, Ordering::Release);
        Some(r)
    }
}
