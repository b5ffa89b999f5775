//! # hil: the Maobi firmware in the loop
//!
//! * [`qemu`]: starting `qemu-system-arm` (`mps2-an386`) under a deadline, with UART0 on a
//!   loopback socket when the host needs the link.
//! * [`firmware`]: building the image (the firmware is its own cargo workspace) and its size.
//! * [`bench`](mod@bench): the firmware's own instruction count of one force-loop tick.
//! * [`cycles`]: the tick's cycle estimate on the Black Pill, from QEMU's execution log and
//!   a Cortex-M4 and flash model.
//! * [`session`]: the host end of the wire protocol: handshake, pose streaming paced by the
//!   device's states, bit-exact comparison with the host simulation.
//! * [`panics`]: the index panics the force loop can reach, read from the image's machine code.
//! * [`run`]: `hil run`: a pose file through the device (QEMU or a serial port), with checks.
//! * [`serial`]: backend `serial`, the same link over a serial port.
//! * [`probe_rs`]: backend `probe-rs`, the firmware flashed onto a board with the `probe-rs`
//!   tool, the link over the pen's USB serial port, the defmt log checked.
//! * [`selftest`]: the boot self-test and the fault-path hooks (panic, HardFault, watchdog).

pub mod bench;
pub mod cycles;
pub mod firmware;
pub mod panics;
pub mod probe_rs;
pub mod qemu;
pub mod run;
pub mod selftest;
pub mod serial;
pub mod session;
