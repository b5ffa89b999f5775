//! `maobi-fw`: the Maobi firmware on QEMU's mps2-an386 (feature `board-qemu`), the virtual
//! pen the host feeds; `cargo run --release` boots it.
#![no_std]
#![no_main]

#[cortex_m_rt::entry]
fn main() -> ! {
    maobi_firmware::qemu::main()
}
