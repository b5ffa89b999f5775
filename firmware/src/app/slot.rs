//! A home for the force loop, which is built at boot (in thread mode) and from then on
//! touched only by the board's force-tick interrupt.

use core::cell::UnsafeCell;
use core::mem::MaybeUninit;
use core::sync::atomic::{AtomicBool, Ordering};

/// Uninitialised storage (in .bss, not copied from flash) until [`ForceLoopSlot::init_with`].
pub struct ForceLoopSlot<L> {
    cell: UnsafeCell<MaybeUninit<L>>,
    ready: AtomicBool,
}

// SAFETY: `init_with` writes the value once, before the force-tick interrupt is enabled (its
// contract); afterwards only that interrupt handler reaches it through `get`, and nothing
// else that preempts the handler touches it.
unsafe impl<L: Send> Sync for ForceLoopSlot<L> {}

impl<L> Default for ForceLoopSlot<L> {
    fn default() -> Self {
        Self::new()
    }
}

impl<L> ForceLoopSlot<L> {
    /// An empty slot (`const`, for a `static`).
    pub const fn new() -> Self {
        ForceLoopSlot {
            cell: UnsafeCell::new(MaybeUninit::uninit()),
            ready: AtomicBool::new(false),
        }
    }

    /// Builds the force loop in place with `build` (which returns None, leaving the slot
    /// empty, if it cannot), and returns it for what remains to set up before the
    /// interrupt starts. Nothing the size of the force loop passes through the stack.
    ///
    /// # Safety
    /// Call once, at boot, before the force-tick interrupt that calls [`Self::get`] is
    /// enabled; the reference returned must not be used after that. `build` returns `Some`
    /// only after it has initialised the slot it was given (as `MaybeUninit::write` does),
    /// and a reference into it.
    #[allow(clippy::mut_from_ref)] // exclusive by the contract above
    pub unsafe fn init_with(
        &self,
        build: impl FnOnce(&mut MaybeUninit<L>) -> Option<&mut L>,
    ) -> Option<&mut L> {
        // SAFETY: by the contract nobody else accesses the cell yet.
        let fl = build(unsafe { &mut *self.cell.get() })?;
        self.ready.store(true, Ordering::SeqCst);
        Some(fl)
    }

    /// The force loop, once initialised.
    ///
    /// # Safety
    /// Only from the force-tick interrupt handler (the single user after `init_with`), and not
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
