//! Maobi pen firmware: one application on two boards.
//!
//! * [`app`]: the force loop (the brush, the force on the hand, the supervisor's faults),
//!   the pose from raw sensor readings, and the hand-off to the link;
//! * [`host_link`]: the pen's end of the link to the host, the wire protocol task;
//! * [`board`]: the traits a board implements; [`executor`]: the thread-mode executor;
//! * a board (exactly one `board-*` feature): `qemu` (QEMU's mps2-an386, the virtual pen,
//!   bin `maobi-fw`) or `blackpill` (the STM32F411CE Black Pill in the real pen, bin
//!   `maobi-pen`). The board owns the entry point, its interrupts and its peripherals.
//!
//! This root builds `maobi-fw` (QEMU); `pen.rs` builds `maobi-pen` (Black Pill) from the same
//! modules (`modules.rs`), so that the runner can tell the images apart by name.
#![no_std]
#![no_main]

include!("modules.rs");
