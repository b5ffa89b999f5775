//! Maobi pen firmware: one application on two boards, a library that each image's bin
//! (`src/bin/`) links.
//!
//! * [`app`]: the force loop (the brush, the force on the hand, the supervisor's faults),
//!   the pose from raw sensor readings, and the hand-off to the link;
//! * [`host_link`]: the pen's end of the link to the host, the wire protocol task;
//! * [`board`]: the traits a board implements; [`executor`]: the thread-mode executor;
//! * a board (exactly one `board-*` feature): `qemu` (QEMU's mps2-an386, the virtual pen,
//!   bins `maobi-fw` and `maobi-fw-hooks`) or `blackpill` (the STM32F411CE Black Pill in
//!   the real pen, bin `maobi-pen`). The board owns its `main` (which the bin's
//!   `#[entry]` calls), its interrupt and fault handlers, the panic handler, the defmt
//!   logger and its peripherals.
//!
//! The handlers are symbols that only the vector table names; they are in the image because
//! the bin's entry point calls its board's `main`, which links this library in whole.
#![no_std]

#[cfg(all(feature = "board-qemu", feature = "board-blackpill"))]
compile_error!(
    "select exactly one board: `board-qemu` is the default; build the Black Pill with \
     `--no-default-features --features board-blackpill`"
);
#[cfg(not(any(feature = "board-qemu", feature = "board-blackpill")))]
compile_error!("select a board feature: `board-qemu` (default) or `board-blackpill`");

pub mod app;
pub mod board;
pub mod executor;
pub mod host_link;

#[cfg(feature = "board-blackpill")]
pub mod blackpill;
#[cfg(feature = "board-qemu")]
pub mod qemu;
