//! CMSDK APB UART0 (0x4000_4000; RX IRQ 0, TX IRQ 1) with interrupt-driven ring buffers.
//!
//! Receive: the RX interrupt moves every received byte into the RX ring (bytes that do not
//! fit are dropped and counted) and wakes the link task. Transmit: `write` appends to the TX
//! ring and starts the transmitter if it is idle; the TX interrupt feeds it the next byte.
//! The rings are guarded by short critical sections (a few instructions per byte).

use core::cell::RefCell;
use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};

use critical_section::Mutex;
use embassy_sync::waitqueue::AtomicWaker;
use heapless::Deque;

use super::regs::{rd, uart as u, wr};
use crate::board::LinkTransport;

const RX_CAP: usize = 2048;
const TX_CAP: usize = 4096;

static RX: Mutex<RefCell<Deque<u8, RX_CAP>>> = Mutex::new(RefCell::new(Deque::new()));
static TX: Mutex<RefCell<Deque<u8, TX_CAP>>> = Mutex::new(RefCell::new(Deque::new()));
/// A byte is in the transmitter (the TX interrupt will come).
static TX_BUSY: AtomicBool = AtomicBool::new(false);
static RX_OVERFLOWS: AtomicU32 = AtomicU32::new(0);
static WAKER: AtomicWaker = AtomicWaker::new();

/// UART0 as the link transport. Only one exists (created by the board).
pub struct Uart0 {
    _private: (),
}

impl Uart0 {
    /// Enables the UART and its interrupts' sources (the NVIC lines are enabled by the board).
    pub(super) fn init() -> Self {
        let b = u::UART0;
        wr(b + u::CTRL, 0);
        wr(b + u::BAUDDIV, 16);
        wr(b + u::INTCLEAR, 0xF);
        wr(
            b + u::CTRL,
            u::CTRL_TX_EN | u::CTRL_RX_EN | u::CTRL_TX_IRQ | u::CTRL_RX_IRQ,
        );
        Uart0 { _private: () }
    }
}

/// Starts sending the next queued byte if the transmitter is idle. Inside a critical section.
fn kick(tx: &mut Deque<u8, TX_CAP>) {
    if TX_BUSY.load(Ordering::Relaxed) || rd(u::UART0 + u::STATE) & u::STATE_TX_FULL != 0 {
        return;
    }
    if let Some(b) = tx.pop_front() {
        TX_BUSY.store(true, Ordering::Relaxed);
        wr(u::UART0 + u::DATA, b as u32);
    }
}

/// Bytes queued for sending and not yet handed to the transmitter (any context).
pub fn tx_queued() -> usize {
    critical_section::with(|cs| TX.borrow(cs).borrow().len())
}

/// RX interrupt (IRQ 0).
pub fn on_rx_interrupt() {
    critical_section::with(|cs| {
        let mut rx = RX.borrow(cs).borrow_mut();
        wr(u::UART0 + u::INTCLEAR, u::INT_RX);
        while rd(u::UART0 + u::STATE) & u::STATE_RX_FULL != 0 {
            let b = rd(u::UART0 + u::DATA) as u8;
            if rx.push_back(b).is_err() {
                RX_OVERFLOWS.fetch_add(1, Ordering::Relaxed);
            }
        }
    });
    WAKER.wake();
}

/// TX interrupt (IRQ 1): the byte has gone; send the next one.
pub fn on_tx_interrupt() {
    critical_section::with(|cs| {
        wr(u::UART0 + u::INTCLEAR, u::INT_TX);
        TX_BUSY.store(false, Ordering::Relaxed);
        kick(&mut TX.borrow(cs).borrow_mut());
    });
    WAKER.wake();
}

/// Bytes queued per critical section by [`Uart0::write`].
const WRITE_CHUNK: usize = 32;

impl LinkTransport for Uart0 {
    fn read(&mut self, buf: &mut [u8]) -> usize {
        critical_section::with(|cs| {
            let mut rx = RX.borrow(cs).borrow_mut();
            let mut n = 0;
            while n < buf.len() {
                match rx.pop_front() {
                    Some(b) => {
                        buf[n] = b;
                        n += 1;
                    }
                    None => break,
                }
            }
            n
        })
    }

    fn write(&mut self, buf: &[u8]) -> usize {
        // A few bytes per critical section: a whole state frame copied with the interrupts
        // masked would hold off the force tick by that copy, enough to make a tick of the
        // pen's pace overrun.
        let mut n = 0;
        for chunk in buf.chunks(WRITE_CHUNK) {
            let fitted = critical_section::with(|cs| {
                let mut tx = TX.borrow(cs).borrow_mut();
                let mut k = 0;
                for &b in chunk {
                    if tx.push_back(b).is_err() {
                        break;
                    }
                    k += 1;
                }
                kick(&mut tx);
                k
            });
            n += fitted;
            if fitted < chunk.len() {
                break;
            }
        }
        n
    }

    fn tx_space(&self) -> usize {
        critical_section::with(|cs| TX_CAP - TX.borrow(cs).borrow().len())
    }

    async fn readable(&mut self) {
        core::future::poll_fn(|cx| {
            WAKER.register(cx.waker());
            if critical_section::with(|cs| !RX.borrow(cs).borrow().is_empty()) {
                core::task::Poll::Ready(())
            } else {
                core::task::Poll::Pending
            }
        })
        .await
    }

    fn rx_overflows(&self) -> u32 {
        RX_OVERFLOWS.load(Ordering::Relaxed)
    }
}
