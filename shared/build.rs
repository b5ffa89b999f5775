//! One name for "the Cortex-M4F's inline assembly applies": `cfg(arm_asm)`.
//!
//! `src/scalar.rs` has a few operations written as Arm assembly (the VFP square root and the
//! fixed-point add, subtract and coefficient multiply) with portable forms for every other
//! target. They need a 32-bit Arm target with a hard-float ABI (ARMv7 or later, which has
//! Thumb-2 and a VFP), which is what `thumbv7em-none-eabihf`, the pen's target, is.
fn main() {
    println!("cargo::rustc-check-cfg=cfg(arm_asm)");
    let arch = std::env::var("CARGO_CFG_TARGET_ARCH").unwrap_or_default();
    let abi = std::env::var("CARGO_CFG_TARGET_ABI").unwrap_or_default();
    if arch == "arm" && abi == "eabihf" {
        println!("cargo::rustc-cfg=arm_asm");
    }
}
