//! The `maobi-pen` image: the Maobi firmware for the STM32F411CE Black Pill (feature
//! `board-blackpill`), the same modules as `maobi-fw` (see `main.rs` and `modules.rs`).
#![no_std]
#![no_main]

include!("modules.rs");
