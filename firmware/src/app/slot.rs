//! A home for the force loop, which is built at boot (in thread mode) and from then on
//! touched only by the board's force-tick interrupt.

use core::cell::UnsafeCell;
use core::mem::MaybeUninit;
use core::sync::atomic::{AtomicBool, Ordering};

/// Uninitialised storage (in .bss, not copied from flash) until [`ForceLoopSlot::init`].
pub struct ForceLoopSlot<L> {
    cell: UnsafeCell<MaybeUninit<L>>,
    ready: AtomicBool,
}

// SAFETY: `init` writes the value once, before the force-tick interrupt is enabled (its
// contract); afterwards only that interrupt handler reaches it through `get`, and nothing
// else that preempts the handler touches it.
unsafe impl<L: Send> Sync for ForceLoopSlot<L> {}

impl<L> ForceLoopSlot<L> {
    pub const fn new() -> Self {
        ForceLoopSlot {
            cell: UnsafeCell::new(MaybeUninit::uninit()),
            ready: AtomicBool::new(false),
        }
    }

    /// Stores the force loop.
    ///
    /// # Safety
    /// Call once, at boot, before the force-tick interrupt that calls [`Self::get`] is
    /// enabled.
    pub unsafe fn init(&self, value: L) {
        // SAFETY: by the contract nobody else accesses the cell yet.
        unsafe { (*self.cell.get()).write(value) };
        self.ready.store(true, Ordering::SeqCst);
    }

    /// The force loop, once initialised.
    ///
    /// # Safety
    /// Only from the force-tick interrupt handler (the single user after `init`), and not
    /// re-entrantly.
    #[allow(clippy::mut_from_ref)] // exclusive by the contract above
    pub unsafe fn get(&self) -> Option<&mut L> {
        if !self.ready.load(Ordering::Acquire) {
            return None;
        }
        // SAFETY: initialised (ready), and by the contract this is the only reference.
        Some(unsafe { (*self.cell.get()).assume_init_mut() })
    }
}
