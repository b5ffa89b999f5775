//! Register addresses and bits of the mps2-an386 peripherals this board uses
//! (ARM CMSDK APB timer, dual timer and UART; QEMU's models of them).

use core::ptr::{read_volatile, write_volatile};

#[inline(always)]
pub fn rd(addr: usize) -> u32 {
    // SAFETY: every address passed in is a 32-bit peripheral register of this machine.
    unsafe { read_volatile(addr as *const u32) }
}

#[inline(always)]
pub fn wr(addr: usize, v: u32) {
    // SAFETY: as for `rd`.
    unsafe { write_volatile(addr as *mut u32, v) }
}

/// Peripheral clock of every CMSDK block on the board (Hz).
pub const PCLK_HZ: u32 = 25_000_000;

/// CMSDK APB timer (down counter, interrupt at zero, reload).
pub mod timer {
    pub const TIMER0: usize = 0x4000_0000;
    pub const TIMER1: usize = 0x4000_1000;
    pub const IRQ_TIMER0: u16 = 8;
    pub const IRQ_TIMER1: u16 = 9;
    pub const CTRL: usize = 0x00;
    pub const VALUE: usize = 0x04;
    pub const RELOAD: usize = 0x08;
    pub const INTCLEAR: usize = 0x0C; // read: INTSTATUS
    pub const CTRL_EN: u32 = 1 << 0;
    pub const CTRL_IRQ_EN: u32 = 1 << 3;
}

/// CMSDK APB dual timer: two 32-bit down counters sharing one interrupt.
pub mod dualtimer {
    pub const BASE: usize = 0x4000_2000;
    pub const IRQ: u16 = 10;
    /// Offset of the first and second counter.
    pub const T1: usize = 0x00;
    pub const T2: usize = 0x20;
    pub const LOAD: usize = 0x00;
    pub const VALUE: usize = 0x04;
    pub const CONTROL: usize = 0x08;
    pub const INTCLR: usize = 0x0C;
    pub const MIS: usize = 0x14;
    pub const CTRL_ONESHOT: u32 = 1 << 0;
    pub const CTRL_32BIT: u32 = 1 << 1;
    pub const CTRL_IRQ_EN: u32 = 1 << 5;
    pub const CTRL_EN: u32 = 1 << 7;
}

/// CMSDK APB UART.
pub mod uart {
    pub const UART0: usize = 0x4000_4000;
    pub const IRQ_RX: u16 = 0;
    pub const IRQ_TX: u16 = 1;
    pub const DATA: usize = 0x00;
    pub const STATE: usize = 0x04;
    pub const CTRL: usize = 0x08;
    pub const INTCLEAR: usize = 0x0C; // read: INTSTATUS
    pub const BAUDDIV: usize = 0x10;
    pub const STATE_TX_FULL: u32 = 1 << 0;
    pub const STATE_RX_FULL: u32 = 1 << 1;
    pub const CTRL_TX_EN: u32 = 1 << 0;
    pub const CTRL_RX_EN: u32 = 1 << 1;
    pub const CTRL_TX_IRQ: u32 = 1 << 2;
    pub const CTRL_RX_IRQ: u32 = 1 << 3;
    pub const INT_TX: u32 = 1 << 0;
    pub const INT_RX: u32 = 1 << 1;
}
