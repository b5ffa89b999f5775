//! # The physical pen's input and output, the parts that need no hardware
//!
//! What a board with real motors and sensors (the STM32F411 "Black Pill" pen) does between its
//! registers and the application, written once here so that the host tests it:
//!
//! * [`drive`]: a motor command in [-1, 1] ([`crate::kinematics::Pen::motor_commands`]) to a
//!   PWM duty, a direction and a brake state for a DRV8833 / TB6612-class H-bridge, with the
//!   bridge's dead zone compensated and the duty clamped ([`DriveConfig`], [`DriveOutput`]).
//! * [`adc`]: the gimbal sensors' filter, median of three and a first-order fixed-point
//!   low-pass ([`AdcFilter`]).
//! * [`config`]: what the pen stores in flash ([`DeviceConfig`]), its validation, and the
//!   flash image format: magic, format version, length, postcard payload, CRC-32
//!   ([`encode`], [`decode`], [`ConfigError`]), older formats migrated ([`load`],
//!   [`Loaded`]); and the state the handshake reports
//!   ([`ConfigState`]); whether that configuration lets the pen render forces and whether
//!   it is calibrated ([`Readiness`], [`ZeroHold`]).
//!
//! * [`config_log`]: where the image lives in NOR flash, a log of slots that survives a
//!   power loss at any moment ([`ConfigLog`], over `embedded-storage`'s `NorFlash`), and
//!   takes over sectors another firmware left data in ([`ConfigLog::reclaim`]).
//! * [`flash_acr`]: the STM32F4 flash accelerator's register values at boot and after every
//!   flash write or erase (prefetch, caches, their reset).
//!
//! Encoder unwrapping is [`crate::kinematics::EncoderUnwrap`] (tested in
//! `shared/tests/pen_io.rs` too).
//!
//! The board supplies only what touches hardware: timer and GPIO registers for
//! [`DriveOutput`], ADC conversions for [`AdcFilter`], its flash driver for [`ConfigLog`].

// Bad input (a flash image, a command) must not panic: no indexing, no unwrap.
#![deny(
    clippy::indexing_slicing,
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic
)]

pub mod adc;
pub mod config;
pub mod config_log;
pub mod drive;
pub mod flash_acr;

pub use adc::AdcFilter;
pub use config::{
    decode, encode, load, ConfigError, ConfigState, DeviceConfig, InvalidField, Loaded,
    OverCurrent, PowerConfig, Readiness, ZeroHold, CONFIG_FORMAT_VERSION, CONFIG_IMAGE_MAX,
    CONFIG_MAGIC, CONFIG_PAYLOAD_MAX, FIELD_LEN, FORMAT_1_PAYLOAD_MAX, IMAGE_HEADER_LEN,
};
pub use config_log::{ConfigLog, LogError, Region};
pub use drive::{Direction, DriveConfig, DriveOutput, ZeroPolicy, ZERO_COMMAND};
/// The flash traits [`ConfigLog`] is generic over, for a board's driver wrapper and for tests.
pub use embedded_storage::nor_flash;
