//! embassy-time driver on the CMSDK dual timer (25 MHz, IRQ 10).
//!
//! * Counter 1 runs free from 0xFFFF_FFFF down and wraps; its wrap interrupt extends it to
//!   64 bits. `now` = elapsed counts / 25 (embassy ticks are microseconds:
//!   `tick-hz-1_000_000`).
//! * Counter 2 is a one-shot alarm, programmed with the distance to the next expiration of
//!   the timer queue (clamped to one wrap; a clamped alarm just re-arms).
//!
//! The force loop does not use this driver (it has its own timer at the highest priority);
//! this one serves the link and supervisor tasks, so its interrupt has a low priority.

use core::cell::{Cell, RefCell};
use core::task::Waker;

use critical_section::{CriticalSection, Mutex};
use embassy_time_driver::Driver;
use embassy_time_queue_utils::Queue;

use super::regs::{dualtimer as dt, rd, wr, PCLK_HZ};

const COUNTS_PER_TICK: u64 = (PCLK_HZ as u64) / embassy_time_driver::TICK_HZ;
const _: () = assert!(COUNTS_PER_TICK * embassy_time_driver::TICK_HZ == PCLK_HZ as u64);

struct DualTimerDriver {
    /// Completed wraps of counter 1.
    wraps: Mutex<Cell<u32>>,
    queue: Mutex<RefCell<Queue>>,
}

embassy_time_driver::time_driver_impl!(static DRIVER: DualTimerDriver = DualTimerDriver {
    wraps: Mutex::new(Cell::new(0)),
    queue: Mutex::new(RefCell::new(Queue::new())),
});

/// Starts counter 1. Call once at boot, before interrupts are enabled.
pub fn init() {
    let t1 = dt::BASE + dt::T1;
    wr(t1 + dt::CONTROL, 0);
    wr(t1 + dt::LOAD, u32::MAX);
    wr(t1 + dt::INTCLR, 1);
    // Free-running (not periodic), 32-bit, interrupt on wrap.
    wr(
        t1 + dt::CONTROL,
        dt::CTRL_EN | dt::CTRL_32BIT | dt::CTRL_IRQ_EN,
    );
    let t2 = dt::BASE + dt::T2;
    wr(t2 + dt::CONTROL, 0);
    wr(t2 + dt::INTCLR, 1);
}

/// Counts (25 MHz) since boot, 64-bit. Also the board's benchmark counter (low 32 bits).
pub fn counts(cs: CriticalSection) -> u64 {
    let t1 = dt::BASE + dt::T1;
    let mut wraps = DRIVER.wraps.borrow(cs).get();
    let mut v = rd(t1 + dt::VALUE);
    if rd(t1 + dt::MIS) & 1 != 0 {
        // Wrapped, but the interrupt has not run yet: count it now and re-read.
        wraps = wraps.wrapping_add(1);
        v = rd(t1 + dt::VALUE);
    }
    ((wraps as u64) << 32) | (u32::MAX - v) as u64
}

/// The low 32 bits of [`counts`], readable without a critical section (for benchmarks).
#[inline(always)]
pub fn counts_lo() -> u32 {
    u32::MAX - rd(dt::BASE + dt::T1 + dt::VALUE)
}

impl DualTimerDriver {
    /// Programs counter 2 to fire at `at` (ticks). Returns false if `at` has already passed.
    fn set_alarm(&self, cs: CriticalSection, at: u64) -> bool {
        let t2 = dt::BASE + dt::T2;
        wr(t2 + dt::CONTROL, 0);
        wr(t2 + dt::INTCLR, 1);
        if at == u64::MAX {
            return true;
        }
        let now = counts(cs);
        let target = at.saturating_mul(COUNTS_PER_TICK);
        if target <= now {
            return false;
        }
        let delta = (target - now).min(u32::MAX as u64) as u32;
        wr(t2 + dt::LOAD, delta);
        wr(
            t2 + dt::CONTROL,
            dt::CTRL_EN | dt::CTRL_32BIT | dt::CTRL_ONESHOT | dt::CTRL_IRQ_EN,
        );
        true
    }

    fn run_queue(&self, cs: CriticalSection) {
        let mut q = self.queue.borrow(cs).borrow_mut();
        let mut next = q.next_expiration(self.now_cs(cs));
        while !self.set_alarm(cs, next) {
            next = q.next_expiration(self.now_cs(cs));
        }
    }

    fn now_cs(&self, cs: CriticalSection) -> u64 {
        counts(cs) / COUNTS_PER_TICK
    }
}

impl Driver for DualTimerDriver {
    fn now(&self) -> u64 {
        critical_section::with(|cs| self.now_cs(cs))
    }

    fn schedule_wake(&self, at: u64, waker: &Waker) {
        critical_section::with(|cs| {
            let changed = self.queue.borrow(cs).borrow_mut().schedule_wake(at, waker);
            if changed {
                self.run_queue(cs);
            }
        });
    }
}

/// The dual timer's interrupt (IRQ 10): counts wraps and runs the timer queue.
pub fn on_interrupt() {
    critical_section::with(|cs| {
        let t1 = dt::BASE + dt::T1;
        if rd(t1 + dt::MIS) & 1 != 0 {
            wr(t1 + dt::INTCLR, 1);
            let w = DRIVER.wraps.borrow(cs);
            w.set(w.get().wrapping_add(1));
        }
        let t2 = dt::BASE + dt::T2;
        if rd(t2 + dt::MIS) & 1 != 0 {
            wr(t2 + dt::INTCLR, 1);
            DRIVER.run_queue(cs);
        }
    });
}
