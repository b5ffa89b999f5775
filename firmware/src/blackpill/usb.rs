//! The link over USB full speed as a CDC-ACM serial port (embassy-usb on the OTG_FS core,
//! PA11/PA12).
//!
//! The device enumerates as `USB_VID:USB_PID` (`maobi_shared::protocol`) with the product
//! string [`USB_PRODUCT`] and the chip's 96-bit unique ID as its serial number, so that two
//! pens on one host keep their names across ports. The link task sees the same
//! non-blocking byte stream as QEMU's UART ([`LinkTransport`]): two pipes between it and
//! the USB task ([`run`]), which moves them to and from 64-byte bulk packets.
//!
//! Receiving waits for room in the receive pipe (USB's flow control then holds the host
//! back: nothing is dropped). Sending does not look at DTR (the host's "a program has the
//! port open", CDC-ACM's SET_CONTROL_LINE_STATE): the pen answers a handshake whatever DTR
//! says, so a host or terminal that never asserts it (Windows leaves it off unless the
//! program asks) does not meet a mute pen. The host asserts it anyway
//! (`host/src/device/endpoint.rs`, `serial_settings`). embassy's `wait_connection` waits for
//! the USB configuration (the endpoints enabled), not for DTR. While the device is not
//! configured (unplugged, enumerating) a packet fails at once and is counted as discarded;
//! while it is configured but no program reads the port, the host does not poll the IN
//! endpoint, the packet in flight waits, the transmit pipe fills and the link drops frames
//! as it does on a busy link ([`LinkTransport::write`] never blocks: the link task does not
//! stall); the next program to open the port reads up to `TX_CAP` stale bytes first,
//! which its decoder skips as it skips any frame before the handshake's answer.

use core::sync::atomic::{AtomicU32, Ordering};

use embassy_futures::join::join3;
use embassy_stm32::peripherals::USB_OTG_FS;
use embassy_stm32::usb::Driver;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::pipe::Pipe;
use embassy_sync::waitqueue::AtomicWaker;
use embassy_usb::class::cdc_acm::{CdcAcmClass, Receiver, Sender, State};
use embassy_usb::driver::EndpointError;
use embassy_usb::UsbDevice;
use maobi_shared::protocol::{USB_PID, USB_PRODUCT, USB_VID};

use crate::board::LinkTransport;

/// The manufacturer string.
pub const USB_MANUFACTURER: &str = "Maobi";
/// Full-speed bulk packets.
const PACKET: usize = 64;
/// Host to device: a few packets; the link task empties it every half tick.
const RX_CAP: usize = 512;
/// Device to host: one state frame of the large brush (under a kilobyte and a half: test
/// `state_frame_size_and_link_share` and `hil run`'s `bytes_per_state`) with room to spare,
/// plus events; a frame is queued whole or not at all (`Link::try_send`), so the
/// largest frame the link sends must fit. The largest device message is 4,114 bytes
/// (`DeviceMsg::MAX_FRAME`); it never occurs in practice, and a frame that does not fit is
/// dropped and counted like any state frame that finds the pipe full.
const TX_CAP: usize = 2048;

static RX: Pipe<CriticalSectionRawMutex, RX_CAP> = Pipe::new();
static TX: Pipe<CriticalSectionRawMutex, TX_CAP> = Pipe::new();
/// Woken when bytes arrive in `RX` (the link task's `readable`).
static RX_WAKER: AtomicWaker = AtomicWaker::new();
/// Bytes the link sent while no host had the port open.
static TX_DISCARDED: AtomicU32 = AtomicU32::new(0);

pub type UsbDriver = Driver<'static, USB_OTG_FS>;

/// The link's end of the pipes. Only one exists (created by the board).
pub struct UsbSerial {
    _private: (),
}

impl UsbSerial {
    pub(super) fn new() -> Self {
        UsbSerial { _private: () }
    }
}

impl LinkTransport for UsbSerial {
    fn read(&mut self, buf: &mut [u8]) -> usize {
        RX.try_read(buf).unwrap_or(0)
    }

    fn write(&mut self, buf: &[u8]) -> usize {
        TX.try_write(buf).unwrap_or(0)
    }

    fn tx_space(&self) -> usize {
        TX.free_capacity()
    }

    async fn readable(&mut self) {
        core::future::poll_fn(|cx| {
            RX_WAKER.register(cx.waker());
            if RX.is_empty() {
                core::task::Poll::Pending
            } else {
                core::task::Poll::Ready(())
            }
        })
        .await
    }

    fn rx_overflows(&self) -> u32 {
        // Flow control: the host waits for room, nothing is dropped on the way in.
        0
    }
}

/// The USB device and its CDC-ACM function, with the buffers they borrow for ever.
pub struct UsbParts {
    device: UsbDevice<'static, UsbDriver>,
    class: CdcAcmClass<'static, UsbDriver>,
}

/// Builds the device descriptor set around `driver`. `serial` is the chip's unique ID in hex.
pub fn build(driver: UsbDriver, serial: &'static str) -> UsbParts {
    let mut config = embassy_usb::Config::new(USB_VID, USB_PID);
    config.manufacturer = Some(USB_MANUFACTURER);
    config.product = Some(USB_PRODUCT);
    config.serial_number = Some(serial);
    // The Black Pill draws its own 3.3 V from the bus; the motors have their own supply.
    config.max_power = 100;
    config.max_packet_size_0 = 64;

    // The descriptors and the control buffer live as long as the device: statics, handed
    // out once (a second call would find them taken and panic at boot, never later).
    static CONFIG_DESC: static_cell::StaticCell<[u8; 256]> = static_cell::StaticCell::new();
    static BOS_DESC: static_cell::StaticCell<[u8; 256]> = static_cell::StaticCell::new();
    static CONTROL_BUF: static_cell::StaticCell<[u8; 64]> = static_cell::StaticCell::new();
    static STATE: static_cell::StaticCell<State<'static>> = static_cell::StaticCell::new();

    let mut builder = embassy_usb::Builder::new(
        driver,
        config,
        CONFIG_DESC.init([0; 256]),
        BOS_DESC.init([0; 256]),
        &mut [], // no Microsoft OS descriptors
        CONTROL_BUF.init([0; 64]),
    );
    let class = CdcAcmClass::new(&mut builder, STATE.init(State::new()), PACKET as u16);
    UsbParts {
        device: builder.build(),
        class,
    }
}

/// The USB task's body: runs the device (enumeration, control requests) and moves bytes
/// between the pipes and the bulk endpoints, for ever.
pub async fn run(parts: UsbParts) -> ! {
    let UsbParts { mut device, class } = parts;
    let (sender, receiver) = class.split();
    join3(device.run(), receive(receiver), send(sender)).await;
    // Each of the three loops for ever; `join3` returns only if all did.
    loop {
        cortex_m::asm::wfi();
    }
}

/// Host to device: packets into the receive pipe, waiting for room.
async fn receive(mut rx: Receiver<'static, UsbDriver>) {
    let mut packet = [0u8; PACKET];
    loop {
        rx.wait_connection().await;
        loop {
            match rx.read_packet(&mut packet).await {
                Ok(n) => {
                    let mut rest = &packet[..n];
                    while !rest.is_empty() {
                        let k = RX.write(rest).await;
                        rest = &rest[k..];
                        RX_WAKER.wake();
                    }
                }
                // Unplugged or reset: wait for the host again.
                Err(EndpointError::Disabled) => break,
                Err(EndpointError::BufferOverflow) => {}
            }
        }
    }
}

/// Device to host: the transmit pipe in packets; a short packet (or a zero-length one after
/// a full packet) ends each burst so that the host's read returns at once.
async fn send(mut tx: Sender<'static, UsbDriver>) {
    let mut packet = [0u8; PACKET];
    loop {
        let n = TX.read(&mut packet).await;
        // Whatever DTR says (see the module's docs): an error only while not configured.
        if tx.write_packet(&packet[..n]).await.is_err() {
            TX_DISCARDED.fetch_add(n as u32, Ordering::Relaxed);
            continue;
        }
        if n == PACKET && TX.is_empty() && tx.write_packet(&[]).await.is_err() {
            continue;
        }
    }
}

/// Bytes the link sent while the device was not configured (unplugged, enumerating).
#[allow(dead_code)] // reported by the boot log and the bring-up
pub fn tx_discarded() -> u32 {
    TX_DISCARDED.load(Ordering::Relaxed)
}
