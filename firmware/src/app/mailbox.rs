//! A one-slot, lock-free hand-off from the force loop (producer, highest priority) to a
//! thread-mode consumer: the consumer requests, the producer fills at the end of its next
//! tick, the consumer takes. Neither side ever waits for the other.

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

    /// Consumer: asks for a fill. False if a request or a value is already outstanding.
    pub fn request(&self) -> bool {
        self.state
            .compare_exchange(IDLE, REQUESTED, Ordering::AcqRel, Ordering::Acquire)
            .is_ok()
    }

    /// Producer: fills the slot if it was requested.
    pub fn fill_if_requested(&self, f: impl FnOnce(&mut T)) {
        if self.state.load(Ordering::Acquire) == REQUESTED {
            // SAFETY: REQUESTED: only the producer (this single context) may touch the slot.
            f(unsafe { &mut *self.slot.get() });
            self.state.store(FULL, Ordering::Release);
        }
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
