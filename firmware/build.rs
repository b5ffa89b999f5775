//! Selects the linker memory layout of the board being built.
//!
//! cortex-m-rt's `link.x` does `INCLUDE memory.x`; the linker finds it in the link search
//! path. Each board keeps its layout under `boards/<board>/memory.x`; this script copies the
//! selected one to `OUT_DIR` and puts `OUT_DIR` first on the search path. The workspace root
//! `memory.x` is the real STM32F411's (a later board) and is never used for QEMU.

use std::{env, fs, path::PathBuf};

fn main() {
    let board = if env::var_os("CARGO_FEATURE_BOARD_QEMU").is_some() {
        "qemu-mps2-an386"
    } else {
        panic!("select a board feature (board-qemu)");
    };
    let src = PathBuf::from("boards").join(board).join("memory.x");
    let out = PathBuf::from(env::var_os("OUT_DIR").unwrap());
    fs::copy(&src, out.join("memory.x")).expect("copy memory.x");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed={}", src.display());
    println!("cargo:rerun-if-changed=build.rs");
}
