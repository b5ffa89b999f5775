//! Selects the linker memory layout of the board being built, and the linker's code folding.
//!
//! cortex-m-rt's `link.x` does `INCLUDE memory.x`; the linker finds it in the link search
//! path. This script copies the selected board's layout to `OUT_DIR` and puts `OUT_DIR`
//! first on the search path:
//!
//! * `board-qemu`: `boards/qemu-mps2-an386/memory.x` (the emulator's memory map);
//! * `board-blackpill`: the workspace root `memory.x` (the STM32F411CE, minus the
//!   configuration sector).
//!
//! It also has the linker fold identical functions in both boards' images.

use std::{env, fs, path::PathBuf};

fn main() {
    let qemu = env::var_os("CARGO_FEATURE_BOARD_QEMU").is_some();
    let blackpill = env::var_os("CARGO_FEATURE_BOARD_BLACKPILL").is_some();
    let src = match (qemu, blackpill) {
        (true, false) => PathBuf::from("boards/qemu-mps2-an386/memory.x"),
        (false, true) => PathBuf::from("../memory.x"),
        // lib.rs says why with a compile_error!; the build script only must not hide it.
        _ => {
            println!("cargo:rerun-if-changed=build.rs");
            return;
        }
    };
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    fs::copy(&src, out.join("memory.x")).unwrap_or_else(|e| panic!("copy {}: {e}", src.display()));
    println!("cargo:rustc-link-search={}", out.display());
    // Identical code folding: the linker keeps one copy of functions whose code is identical
    // (the monomorphisations that compile to the same instructions, the empty trait methods,
    // the aliases of memcpy and memclr): flash the Black Pill's image needs, since the
    // application became a library that each bin links. `all`, not `safe`: this target's
    // objects carry no address-significance table, without which `safe` folds nothing; Rust
    // gives function addresses no uniqueness, and lld folds no data by this flag.
    println!("cargo:rustc-link-arg-bins=--icf=all");
    println!("cargo:rerun-if-changed={}", src.display());
    println!("cargo:rerun-if-changed=build.rs");
}
