//! The link task (placeholder until the wire protocol lands): drains the UART.

use crate::board::LinkTransport;
use crate::qemu::Parts;

#[embassy_executor::task]
pub async fn link_task(mut parts: Parts) {
    let mut buf = [0u8; 64];
    loop {
        parts.uart.readable().await;
        let _ = parts.uart.read(&mut buf);
    }
}
