//! The independent watchdog (IWDG, on the 32 kHz LSI), fed by the force tick only when the
//! thread-mode supervisor has checked in since the last feed (`app::ForceLoop::tick`, the
//! same code on every board): if either stops, the force loop (no tick feeds it) or thread
//! mode (a task that never yields, or interrupts that leave it no time: no check-in), the
//! chip resets within [`TIMEOUT_US`], and a reset leaves every motor pin an input (the
//! carriers' standby inputs are pulled low on the TB6612 boards: off). The next boot reports
//! the watchdog's reset (`Faults::WATCHDOG`).
//!
//! [`Stretch`] lengthens it for the deliberate stalls, a configuration store (thread mode
//! programs the flash without yielding, so the supervisor cannot check in) and each
//! configuration-sector erase (seconds with the core waiting on flash), and puts it back
//! after.
//!
//! Once started, the IWDG runs until the next reset: nothing stops it. Only the debug halt
//! freezes it ([`freeze_in_debug`]), and a fatal boot error feeds it ([`feed_now`], from
//! `fatal`) rather than reset into the same error again and again.

use embassy_stm32::pac;
use embassy_stm32::pac::iwdg::vals::{Key, Pr};
use embassy_stm32::wdg::IndependentWatchdog;

use crate::board::Watchdog;

/// Reset after this long without a feed: 80 ticks at 1 kHz as embassy sets it up (for a
/// 32 kHz LSI). The LSI may run anywhere from 17 to 47 kHz, so in fact 54 to 150 ms: at the
/// fastest, still more than [`crate::app::WATCHDOG_MIN_TICKS`] (five of the supervisor's
/// check-in periods; checked beside the board's `TICK_US`), so a live but busy thread mode
/// does not trip it; at the slowest, still far below what a hand notices.
pub const TIMEOUT_US: u32 = 80_000;

/// The LSI's fastest (kHz, the datasheet's maximum) over the 32 kHz embassy assumes.
pub(super) const LSI_FASTEST_KHZ: u32 = 47;

pub struct Iwdg(pub(super) IndependentWatchdog<'static, embassy_stm32::peripherals::IWDG>);

impl Watchdog for Iwdg {
    #[inline]
    fn feed(&mut self) {
        self.0.pet();
    }
}

/// Writes the prescaler and reload (waiting until the previous write has reached the
/// watchdog's clock domain) and reloads the counter.
fn set(pr: Pr, reload: u16) {
    let w = pac::IWDG;
    while w.sr().read().pvu() || w.sr().read().rvu() {}
    w.kr().write(|k| k.set_key(Key::ENABLE));
    w.pr().write(|p| p.set_pr(pr));
    w.rlr().write(|r| r.set_rl(reload));
    w.kr().write(|k| k.set_key(Key::RESET));
}

/// The watchdog at its longest (LSI / 256, the full 12-bit reload: tens of seconds even at
/// the fastest LSI the datasheet allows, far beyond a sector erase) while this value lives;
/// [`TIMEOUT_US`] again after.
pub struct Stretch {
    saved: (Pr, u16),
}

impl Stretch {
    pub fn begin() -> Self {
        let w = pac::IWDG;
        while w.sr().read().pvu() || w.sr().read().rvu() {}
        let saved = (w.pr().read().pr(), w.rlr().read().rl());
        set(Pr::DIVIDE_BY256, 0x0FFF);
        Stretch { saved }
    }
}

impl Drop for Stretch {
    fn drop(&mut self) {
        set(self.saved.0, self.saved.1);
    }
}

/// Reloads the watchdog's counter from any context, without the driver object (a reload
/// key write; harmless if the watchdog was never started).
pub fn feed_now() {
    pac::IWDG.kr().write(|k| k.set_key(Key::RESET));
}

/// Keeps the watchdog from resetting the chip while a debugger halts the core (probe-rs
/// breakpoints, `probe-rs attach`).
pub fn freeze_in_debug() {
    pac::DBGMCU.apb1fzr().modify(|r| r.set_iwdg(true));
}
