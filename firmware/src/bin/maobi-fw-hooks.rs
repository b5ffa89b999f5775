//! `maobi-fw-hooks`: the QEMU image with the firmware's test hooks (feature `test-hooks`:
//! fault injection over the link, the `crash` boot modes), for the hil tests. The same
//! boot as `maobi-fw`, under its own name so that building it never replaces the plain
//! image.
#![no_std]
#![no_main]

#[cortex_m_rt::entry]
fn main() -> ! {
    maobi_firmware::qemu::main()
}
